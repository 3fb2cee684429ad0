"""What the car's router itself refuses (compose/zenoh/router.json5, issues 15 and 24):
commands, put or asked, faster than any person or pilot sends them, from any one client. A
flood of setpoints or arms then costs the steering service little, whoever sends it, and
the owner's commands, on their own connection, pass as before."""
from __future__ import annotations

import threading
import time

import json5
import pytest
import zenoh
from vienatest import wait_until

from viena.common.access import ROLES
from viena.common.config import load_zenoh_config
from viena.common.paths import compose_dir

KEY = "viena/elettra/steering/setpoint"
#: the limit router.json5 sets per client and command key on puts
LIMIT_HZ = 200.0
#: and on queries: a stream of setpoints, and one-off commands
QUERY_LIMITS_HZ = {"steering/setpoint": 200.0, "steering/arm": 20.0, "steering/calibration": 20.0,
                   "steering/estop": 20.0, "pilot/route": 20.0, "pilot/cmd": 20.0}


def downsampling(item: str) -> dict:
    conf = json5.loads((compose_dir() / "zenoh" / "router.json5").read_text())
    [found] = [d for d in conf["downsampling"] if d["id"] == item]
    assert found["flows"] == ["ingress"]                  # per client connection, as it arrives
    return found


def test_the_router_limits_exactly_the_keys_services_take_commands_on_as_puts():
    """The keys a role receives as puts (common/access.py) are the commands a flood could
    aim at; the router limits those and no others (a key dropped from the roles goes from
    the limits too)."""
    commands = downsampling("commands")
    assert set(commands["messages"]) == {"put", "delete"}
    limited = {rule["key_expr"] for rule in commands["rules"]}
    assert limited == {f"viena/*/{key}" for role in ROLES.values() for key in role.receive}
    assert {rule["freq"] for rule in commands["rules"]} == {LIMIT_HZ}


def test_the_router_limits_exactly_the_keys_roles_may_ask_as_commands():
    """Every key a role may query (common/access.py's `command`) runs Python in the
    service that answers it, refused or not: the router limits queries on those and no
    others, setpoints as a stream and the rest as one-off commands."""
    queries = downsampling("command-queries")
    assert queries["messages"] == ["query"]
    limits = {rule["key_expr"]: rule["freq"] for rule in queries["rules"]}
    assert set(limits) == {f"viena/*/{key}" for role in ROLES.values() for key in role.command}
    assert limits == {f"viena/*/{key}": hz for key, hz in QUERY_LIMITS_HZ.items()}


def reach(send, hello: bytes, count) -> None:
    """Send `hello` (put or ask) every 50 ms until it is heard: the client's route is in
    place (a put made before it is lost, and would count as cut by the limit). Then wait for
    the ones still in flight (at most 1 s: those sent before the route was there never
    come), so that none reaches the router just before the client's next one."""
    sent = 0

    def heard_or_send() -> bool:
        nonlocal sent
        if count(hello) > 0:
            return True
        send(hello)
        sent += 1
        return False
    assert wait_until(heard_or_send, 20, period=0.05), hello
    wait_until(lambda: count(hello) >= sent, 1)


class Heard:
    """How many of each payload arrived, by put or by query."""

    def __init__(self):
        self._lock = threading.Lock()
        self._heard: dict[bytes, int] = {}

    def add(self, tag: bytes) -> None:
        with self._lock:
            self._heard[tag] = self._heard.get(tag, 0) + 1

    def __call__(self, tag: bytes) -> int:
        with self._lock:
            return self._heard.get(tag, 0)


def flood_with_an_owner(flood, owner, count) -> tuple[int, int, float]:
    """5,000 flood messages as fast as they go; the owner's one per 250 of them, each once
    the one before it has come through and 20 ms later, so never faster than 50 Hz at the
    router however late this thread runs (the wait gives up on one the router cut).
    (flood messages sent, the owner's, seconds the flood took)."""
    t0 = time.monotonic()
    sent = owned = 0
    while sent < 5000:
        flood(b"flood")
        sent += 1
        if sent % 250 == 0:
            wait_until(lambda n=owned: count(b"owner") >= n, 5)
            time.sleep(0.02)
            owner(b"owner")
            owned += 1
    flooding_s = time.monotonic() - t0
    wait_until(lambda: count(b"owner") >= owned, 5)
    time.sleep(0.2)                                         # the last flood messages in flight
    return sent, owned, flooding_s


@pytest.mark.slow
@pytest.mark.realtime                   # counts what passes a rate limit in real time
def test_a_setpoint_flood_from_one_client_is_cut_to_the_limit_and_another_client_still_passes(router, session):
    count = Heard()
    sub = session.declare_subscriber(KEY, lambda sample: count.add(sample.payload.to_bytes()))
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as flooder, \
            zenoh.open(load_zenoh_config(mode="client", connect=[router])) as owner:
        flood_pub, owner_pub = flooder.declare_publisher(KEY), owner.declare_publisher(KEY)
        for pub, hello in ((flood_pub, b"hello flood"), (owner_pub, b"hello owner")):
            reach(pub.put, hello, count)
        sent, owned, flooding_s = flood_with_an_owner(flood_pub.put, owner_pub.put, count)
    sub.undeclare()
    assert owned == 20
    assert count(b"owner") == 20                            # the owner's every setpoint
    assert count(b"flood") <= LIMIT_HZ * flooding_s + 2
    assert count(b"flood") < sent / 2, (count(b"flood"), flooding_s)


@pytest.mark.slow
@pytest.mark.realtime                   # counts what passes a rate limit in real time
def test_a_query_flood_from_one_client_is_cut_to_the_limit_and_another_client_still_passes(router, session):
    """The same as puts, for setpoint queries sent without waiting for their answers (what
    took the steering's p99 from 10 to 254 ms in issue 24): the flooder gets its limit's
    worth through, the owner, asking and waiting for each answer, every one."""
    count = Heard()
    answered = Heard()

    def answer(query) -> None:
        count.add(query.payload.to_bytes())
        query.reply(query.key_expr, b"refused")

    queryable = session.declare_queryable(KEY, answer)
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as flooder, \
            zenoh.open(load_zenoh_config(mode="client", connect=[router])) as owner:
        def flood(tag: bytes) -> None:
            flooder.get(KEY, payload=tag, handler=lambda reply: None)

        def ask(tag: bytes) -> None:
            for reply in owner.get(KEY, payload=tag, timeout=5.0):
                if reply.ok is not None:
                    answered.add(tag)

        for send, hello in ((flood, b"hello flood"), (ask, b"hello owner")):
            reach(send, hello, count)
        sent, owned, flooding_s = flood_with_an_owner(flood, ask, count)
    queryable.undeclare()
    assert owned == 20
    assert count(b"owner") == answered(b"owner") == 20     # the owner's every setpoint, answered
    assert count(b"flood") <= QUERY_LIMITS_HZ["steering/setpoint"] * flooding_s + 2
    assert count(b"flood") < sent / 2, (count(b"flood"), flooding_s)


def test_the_steering_client_asks_no_faster_than_the_router_lets_queries_through():
    """A query sooner than the router's limit is dropped unanswered: SteeringClient spaces
    its questions on each key at least as far apart as router.json5 says."""
    from viena.services.steering.client import ONE_OFF_QUERY_SPACING_S, QUERY_SPACING_S

    conf = json5.loads((compose_dir() / "zenoh" / "router.json5").read_text())
    [queries] = [d for d in conf["downsampling"] if d["id"] == "command-queries"]
    for rule in queries["rules"]:
        service, name = rule["key_expr"].split("/")[-2:]
        if service == "steering":
            assert QUERY_SPACING_S.get(name, ONE_OFF_QUERY_SPACING_S) >= 1 / rule["freq"], rule
