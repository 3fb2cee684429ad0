"""What the car's router itself refuses (compose/zenoh/router.json5, issue 15): commands
faster than any person or pilot sends them, from any one client. A flood of setpoints then
costs the steering service nothing, whoever sends it, and the owner's commands, on their
own connection, pass as before."""
from __future__ import annotations

import threading
import time

import json5
import pytest
import zenoh
from vienatest import wait_until

from viena.common.access import ROLES
from viena.common.config import load_zenoh_config
from viena.paths import compose_dir

KEY = "viena/elettra/steering/setpoint"
#: the limit router.json5 sets per client and command key
LIMIT_HZ = 200.0


def test_the_router_limits_exactly_the_keys_services_take_commands_on_as_puts():
    """The keys a role receives as puts (common/access.py) are the commands a flood could
    aim at; the router limits those and no others (a key dropped from the roles goes from
    the limits too)."""
    conf = json5.loads((compose_dir() / "zenoh" / "router.json5").read_text())
    [commands] = [d for d in conf["downsampling"] if d["id"] == "commands"]
    assert commands["flows"] == ["ingress"] and set(commands["messages"]) == {"put", "delete"}
    limited = {rule["key_expr"] for rule in commands["rules"]}
    assert limited == {f"viena/*/{key}" for role in ROLES.values() for key in role.receive}
    assert {rule["freq"] for rule in commands["rules"]} == {LIMIT_HZ}


def reach(pub, hello: bytes, count) -> None:
    """Put `hello` every 50 ms until the subscriber hears one: the client's route is in
    place (a put made before it is lost, and would count as cut by the limit). Then wait for
    the ones still in flight (at most 1 s: those sent before the route was there never
    come), so that none reaches the router just before the client's next put."""
    sent = 0

    def heard_or_put() -> bool:
        nonlocal sent
        if count(hello) > 0:
            return True
        pub.put(hello)
        sent += 1
        return False
    assert wait_until(heard_or_put, 20, period=0.05), hello
    wait_until(lambda: count(hello) >= sent, 1)


@pytest.mark.slow
@pytest.mark.realtime                   # counts what passes a rate limit in real time
def test_a_setpoint_flood_from_one_client_is_cut_to_the_limit_and_another_client_still_passes(router, session):
    heard: dict[bytes, int] = {}
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            tag = sample.payload.to_bytes()
            heard[tag] = heard.get(tag, 0) + 1

    def count(tag: bytes) -> int:
        with lock:
            return heard.get(tag, 0)

    sub = session.declare_subscriber(KEY, on_sample)
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as flooder, \
            zenoh.open(load_zenoh_config(mode="client", connect=[router])) as owner:
        flood_pub, owner_pub = flooder.declare_publisher(KEY), owner.declare_publisher(KEY)
        for pub, hello in ((flood_pub, b"hello flood"), (owner_pub, b"hello owner")):
            reach(pub, hello, count)
        t0 = time.monotonic()
        sent = owned = 0
        while sent < 5000:
            flood_pub.put(b"flood")
            sent += 1
            if sent % 250 == 0:
                # the owner: one setpoint per 250 flood puts, each once the one before it has
                # come through and 20 ms later, so never faster than 50 Hz at the router
                # however late this thread runs (the wait gives up on a setpoint the router cut)
                wait_until(lambda n=owned: count(b"owner") >= n, 5)
                time.sleep(0.02)
                owner_pub.put(b"owner")
                owned += 1
        flooding_s = time.monotonic() - t0
        wait_until(lambda: count(b"owner") >= owned, 5)
        time.sleep(0.2)                                     # the last flood puts in flight
    sub.undeclare()
    assert owned == 20
    assert heard.get(b"owner") == 20, heard                 # the owner's every setpoint
    assert heard.get(b"flood", 0) <= LIMIT_HZ * flooding_s + 2
    assert heard.get(b"flood", 0) < sent / 2, (heard, flooding_s)
