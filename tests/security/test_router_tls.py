"""A real `viena router` on TLS with the car's access control, and real zenoh clients:
who gets a session, and what each role's messages reach."""
from __future__ import annotations

import datetime as dt
import json
import queue
import time
from contextlib import contextmanager

import pytest
import zenoh
from vienatest import free_port, wait_for_queryable, wait_for_subscriber

from viena.common.config import load_zenoh_config
from viena.common.keystore import KeyStore
from viena.common.secure import secure_client

pytestmark = pytest.mark.slow  # a TLS router per test

CAR = "viena/elettra"


def raw_client(port: int, cert=None, key=None, ca=None, scheme="tls"):
    """A client config built by hand, bypassing viena's own checks: what an attacker has."""
    conf = load_zenoh_config(mode="client", connect=[f"{scheme}/localhost:{port}"])
    if ca is not None:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(ca)))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    if cert is not None:
        conf.insert_json5("transport/link/tls/connect_certificate", json.dumps(str(cert)))
        conf.insert_json5("transport/link/tls/connect_private_key", json.dumps(str(key)))
    return conf


@contextmanager
def client(store: KeyStore, name: str, port: int):
    conf = load_zenoh_config(mode="client", connect=[f"tls/localhost:{port}"])
    secure_client(conf, store, name)
    session = zenoh.open(conf)
    try:
        yield session
    finally:
        session.close()


def received(session, keyexpr: str) -> queue.Queue:
    q: queue.Queue = queue.Queue()
    session.declare_subscriber(keyexpr, lambda s: q.put((str(s.key_expr), s.payload.to_bytes())))
    return q


def drain(q: queue.Queue, wait_s: float = 1.0) -> list:
    end, out = time.monotonic() + wait_s, []
    while time.monotonic() < end:
        try:
            out.append(q.get(timeout=0.05))
        except queue.Empty:
            pass
    return out


def test_the_car_identities_open_sessions(store, tls_router):
    for name in ("gnss0", "steering", "estimator", "pilot", "observer"):
        with client(store, name, tls_router) as session:
            assert session.info.zid() is not None


def test_no_certificate_no_session(store, tls_router):
    with pytest.raises(zenoh.ZError):
        zenoh.open(raw_client(tls_router, ca=store.ca_cert))


def test_plain_tcp_to_the_tls_port_gets_no_session(tls_router):
    with pytest.raises(zenoh.ZError):
        zenoh.open(raw_client(tls_router, scheme="tcp"))


def test_certificate_of_another_ca_gets_no_session(store, tls_router, tmp_path):
    thief = KeyStore(tmp_path / "thief", "elettra")
    thief.init()                                 # a CA of its own, a 'pilot' with the right name
    conf = raw_client(tls_router, thief.dir / "pilot.pem", thief.dir / "pilot.key", ca=store.ca_cert)
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


def test_expired_certificate_gets_no_session(store, tls_router):
    long_ago = dt.datetime.now(dt.UTC) - dt.timedelta(days=40)
    expired = store.issue("pilot", "expired-pilot", days=10, valid_from=long_ago)
    with pytest.raises(zenoh.ZError):
        zenoh.open(raw_client(tls_router, expired.cert, expired.key, ca=store.ca_cert))


def test_a_device_publishes_only_on_its_own_keys(store, tls_router):
    with client(store, "observer", tls_router) as watcher, \
            client(store, "gnss0", tls_router) as gnss0, client(store, "gnss1", tls_router) as gnss1:
        got = received(watcher, f"{CAR}/**")
        for unit, session in (("gnss0", gnss0), ("gnss1", gnss1)):      # the router has it
            assert wait_for_subscriber(session, f"{CAR}/gnss/{unit}/fix")
        gnss0.put(f"{CAR}/gnss/gnss1/fix", b"spoofed by gnss0")
        gnss0.put(f"{CAR}/imu/razor0/sample", b"spoofed by gnss0")
        gnss0.put(f"{CAR}/gnss/gnss0/fix", b"gnss0's own")
        gnss1.put(f"{CAR}/gnss/gnss1/fix", b"gnss1's own")
        samples = drain(got)
    assert sorted(samples) == [(f"{CAR}/gnss/gnss0/fix", b"gnss0's own"),
                               (f"{CAR}/gnss/gnss1/fix", b"gnss1's own")]


def test_an_observer_watches_and_may_stop_but_publishes_nothing_else(store, tls_router):
    with client(store, "observer", tls_router) as observer, \
            client(store, "estimator", tls_router) as estimator, \
            client(store, "steering", tls_router) as steering:
        fixes = received(estimator, f"{CAR}/gnss/*/fix")
        estops = received(steering, f"{CAR}/steering/estop")
        assert wait_for_subscriber(observer, f"{CAR}/gnss/gnss0/fix")
        assert wait_for_subscriber(observer, f"{CAR}/steering/estop")
        observer.put(f"{CAR}/gnss/gnss0/fix", b"spoofed fix")
        observer.put(f"{CAR}/steering/setpoint", b'{"angle_deg": 20}')
        observer.put(f"{CAR}/steering/estop", b"{}")
        assert drain(fixes) == []
        assert drain(estops) == [(f"{CAR}/steering/estop", b"{}")]


@contextmanager
def steering_queryables(session, answer: bytes):
    """Answers every steering command with `answer`; counts the queries it saw."""
    seen: list[str] = []

    def reply(query):
        seen.append(str(query.key_expr))
        query.reply(query.key_expr, answer)

    qs = [session.declare_queryable(f"{CAR}/steering/{name}", reply)
          for name in ("arm", "setpoint", "calibration", "estop")]
    try:
        yield seen
    finally:
        for q in qs:
            q.undeclare()


def ask(session, key: str) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(key, payload=b'{"arm": true}', timeout=2.0)
            if r.ok is not None]


def test_only_a_pilot_commands_and_only_the_steering_service_answers(store, tls_router):
    if not (store.dir / "mallory.pem").exists():
        store.issue("pilot", "mallory")
    with client(store, "steering", tls_router) as steering, \
            client(store, "pilot", tls_router) as pilot, \
            client(store, "observer", tls_router) as observer, \
            client(store, "observer", tls_router) as rogue_observer, \
            client(store, "mallory", tls_router) as rogue_pilot, \
            steering_queryables(steering, b"the steering service") as seen, \
            steering_queryables(rogue_observer, b"a rogue observer"), \
            steering_queryables(rogue_pilot, b"a rogue pilot"):
        for name in ("arm", "setpoint", "calibration", "estop"):
            assert wait_for_queryable(pilot, f"{CAR}/steering/{name}")
        for name in ("arm", "setpoint", "calibration"):
            assert ask(observer, f"{CAR}/steering/{name}") == []
        assert seen == []
        for name in ("arm", "setpoint", "calibration", "estop"):
            assert ask(pilot, f"{CAR}/steering/{name}") == [b"the steering service"]
        assert ask(pilot, f"{CAR}/**") == []             # a discovery query reaches no command
        assert ask(pilot, f"{CAR}/steering/*") == []
        assert seen == [f"{CAR}/steering/{n}" for n in ("arm", "setpoint", "calibration", "estop")]


def test_router_refuses_an_open_listener_others_can_reach(procs):
    proc = procs.python("-m", "viena.router", "--listen", f"tcp/0.0.0.0:{free_port()}")
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 2
    assert err.startswith("viena router: refusing to listen on tcp/0.0.0.0:") and err.count("\n") == 1
    assert "viena keys init" in err and "--insecure" in err


def test_an_insecure_router_says_so(procs):
    port = free_port()
    proc = procs.python("-m", "viena.router", "--listen", f"tcp/0.0.0.0:{port}", "--insecure")
    started, warning = proc.stderr.readline(), proc.stderr.readline()
    assert "INSECURE" in started
    assert "WARNING" in warning and "anyone on the network can steer" in warning, warning


def test_router_with_tls_and_plain_listeners_is_refused(procs, store):
    proc = procs.python("-m", "viena.router", "--keys", str(store.dir),
                        "--listen", f"tls/127.0.0.1:{free_port()}", "--listen", f"tcp/127.0.0.1:{free_port()}")
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 2 and "listen on tls/ only" in err
