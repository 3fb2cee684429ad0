"""A router run from the Pi's store, made as docs/deployment.md says (`viena keys export` of
the car's identities: no ca.key, people by their certificates alone), admits people by the
role their certificate carries; after a re-issue, a revocation, or a name moved from
observer to pilot, and a restart, the old certificates are granted nothing."""
from __future__ import annotations

import shutil
import signal
from contextlib import ExitStack, contextmanager

import pytest
import zenoh
from test_router_tls import ask, client, drain, raw_client, received, steering_queryables
from vienatest import free_port, wait_for_line, wait_for_port, wait_for_queryable, wait_for_subscriber

from viena.common.keystore import KeyStore
from viena.keys_cli import main as keys

pytestmark = pytest.mark.slow  # two TLS routers

CAR = "viena/elettra"
#: what the Pi runs, exported exactly as docs/deployment.md says
PI = ["router", "gnss0", "gnss1", "razor0", "steering", "estimator", "autopilot"]
SETPOINT, ESTOP = f"{CAR}/steering/setpoint", f"{CAR}/steering/estop"


def router_on(procs, pi: KeyStore):
    """`viena router` on the Pi's store; (process, port)."""
    port = free_port()
    proc = procs.python("-m", "viena.router", "--listen", f"tls/127.0.0.1:{port}", "--keys", str(pi.dir),
                        "--log-level", "WARNING")
    wait_for_port(port)
    return proc, port


def stop(proc) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    return err


def keep(store: KeyStore, name: str, where) -> tuple:
    """A copy of `name`'s certificate and key as they are now: what its holder keeps."""
    where.mkdir(exist_ok=True)
    for suffix in (".pem", ".key"):
        shutil.copy(store.dir / f"{name}{suffix}", where / f"{name}{suffix}")
    return where / f"{name}.pem", where / f"{name}.key"


@contextmanager
def presenting(port: int, ca, cert, key):
    with zenoh.open(raw_client(port, cert, key, ca=ca)) as session:
        yield session


@contextmanager
def the_steering(pi: KeyStore, port: int):
    """The steering service's session (its key is on the Pi): answers the commands, takes puts."""
    with client(pi, "steering", port) as steering, steering_queryables(steering, b"the steering service"):
        yield received(steering, SETPOINT), received(steering, ESTOP)


def test_people_are_admitted_by_their_certificates_and_old_ones_are_refused(procs, tmp_path):
    trusted = KeyStore(tmp_path / "trusted", "elettra")
    trusted.init()
    for name, role in (("alice", "pilot"), ("bob", "observer"), ("carol", "observer")):
        trusted.issue(role, name)
    pi = KeyStore(tmp_path / "pi", "elettra")
    assert keys(["--keys", str(trusted.dir), "export", *PI, "-o", str(pi.dir)]) == 0
    assert sorted(p.stem for p in pi.dir.glob("*.key")) == sorted(PI)        # no ca.key, no person's

    router, port = router_on(procs, pi)
    with the_steering(pi, port) as (setpoints, estops), client(trusted, "alice", port) as alice, \
            client(trusted, "bob", port) as bob, client(trusted, "carol", port) as carol:
        assert wait_for_queryable(alice, f"{CAR}/steering/arm") and wait_for_subscriber(alice, SETPOINT)
        assert wait_for_subscriber(bob, ESTOP)
        assert ask(alice, f"{CAR}/steering/arm") == [b"the steering service"]      # a pilot
        alice.put(SETPOINT, b"alice")
        assert ask(bob, f"{CAR}/steering/arm") == [] and ask(carol, f"{CAR}/steering/arm") == []
        bob.put(SETPOINT, b"bob")
        bob.put(ESTOP, b"bob")                                                      # an observer
        assert drain(setpoints) == [(SETPOINT, b"alice")] and drain(estops) == [(ESTOP, b"bob")]

    old = {name: keep(trusted, name, tmp_path / "held") for name in ("alice", "bob", "carol")}
    assert keys(["--keys", str(trusted.dir), "issue", "pilot", "alice", "--force"]) == 0
    assert keys(["--keys", str(trusted.dir), "revoke", "bob"]) == 0
    assert keys(["--keys", str(trusted.dir), "issue", "pilot", "carol", "--force"]) == 0
    assert keys(["--keys", str(trusted.dir), "export", *PI, "-o", str(pi.dir), "--force"]) == 0
    shutil.copy(old["bob"][0], pi.dir / "bob.pem")      # a stale copy of bob's certificate: the CRL refuses it
    assert stop(router) is not None
    router, port = router_on(procs, pi)
    assert "not admitted: " in wait_for_line(router.stderr, "bob.pem: revoked on")

    with the_steering(pi, port) as (setpoints, estops), ExitStack() as held:
        alice, carol = (held.enter_context(client(trusted, n, port)) for n in ("alice", "carol"))
        old_alice, old_bob, old_carol = (held.enter_context(presenting(port, trusted.ca_cert, *old[n]))
                                         for n in ("alice", "bob", "carol"))
        assert wait_for_queryable(alice, f"{CAR}/steering/arm") and wait_for_subscriber(alice, SETPOINT)
        assert wait_for_subscriber(alice, ESTOP)
        for session in (old_alice, old_bob, old_carol):           # a TLS session, and nothing else
            assert ask(session, f"{CAR}/steering/arm") == []
            session.put(SETPOINT, b"old")
            session.put(ESTOP, b"old")
        for session, name in ((alice, b"alice"), (carol, b"carol")):
            assert ask(session, f"{CAR}/steering/arm") == [b"the steering service"]
            session.put(SETPOINT, name)
        assert sorted(drain(setpoints)) == [(SETPOINT, b"alice"), (SETPOINT, b"carol")]
        assert drain(estops, 0.2) == []
