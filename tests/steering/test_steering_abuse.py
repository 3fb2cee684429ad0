"""What a buggy or compromised client can do to `viena-steering` (issue 15): discovery
queries, empty and absurd commands, huge and deep payloads, impostors and floods. Each of
these acted on, crashed or starved the service before; now each gets a reason or nothing,
and the owner keeps the wheel."""
from __future__ import annotations

import json
import time

import msgpack
import pytest
import zenoh
from test_steering_service import KEY, get, service, twin  # noqa: F401  (fixtures)
from vienatest import signed, wait_for_line

from viena.services.steering.client import ConflictingReplies, SteeringClient

pytestmark = [pytest.mark.slow,  # floods against a steering and its drive twin, with watchdogs: in the
              pytest.mark.car(seconds=60)]    # in the car lane, not beside another car


def arm(session) -> str:
    return json.loads(get(session, "arm", b'{"arm": true}')[0])["lease"]


def test_a_discovery_query_describes_and_never_stops_the_car(service, session):
    proc, latest, until = service
    lease = arm(session)
    time.sleep(0.1)            # the router counts a wildcard query against each command key it covers
    replies = [r.ok for r in session.get("viena/**", timeout=3.0) if r.ok is not None]
    descriptions = [json.loads(r.payload.to_bytes()) if r.payload.to_bytes()[:1] == b"{"
                    else msgpack.unpackb(r.payload.to_bytes()) for r in replies]
    assert {d["key"].rsplit("/", 1)[1] for d in descriptions} == {"arm", "setpoint", "calibration", "estop"}
    assert all(d["status"] == "description" for d in descriptions)
    session.put(f"{KEY}/setpoint", json.dumps(signed({"angle_deg": 1.0, "lease": lease})))
    assert until(lambda st: st["armed"] and st["trip"] == ""), latest       # still the owner's


def test_an_empty_estop_query_is_an_accident_a_map_is_an_estop(service, session):
    proc, latest, until = service
    arm(session)
    data, _ = get(session, "estop", b"")
    assert msgpack.unpackb(data)["status"] == "rejected"
    assert until(lambda st: st["armed"]), latest
    data, _ = get(session, "estop", b"{}")
    assert until(lambda st: not st["armed"] and st["trip"] == "estop"), latest


@pytest.mark.parametrize("angle", [1.8e19, 1e308, -1e300, 90.0])
def test_absurd_setpoints_are_refused_not_clamped(service, session, angle):
    proc, latest, until = service
    lease = arm(session)
    data, _ = get(session, "setpoint", json.dumps(signed({"angle_deg": angle, "lease": lease})).encode())
    reply = json.loads(data)
    assert reply["status"] == "rejected" and reply["reason"].startswith("absurd"), reply


def test_huge_and_deep_payloads_get_a_reason_not_a_traceback(service, session):
    proc, latest, until = service
    for payload, why in ((b'{"arm": "' + b"x" * 100_000 + b'"}', "bytes: at most"),
                         (b"[" * 2000 + b"]" * 2000, "nested deeper"),
                         (msgpack.packb({"a": [[[[[[[[[[1]]]]]]]]]]}), "nested deeper")):
        for _ in range(10):
            data, _ = get(session, "arm", payload)
        reason = (json.loads(data) if data[:1] == b"{" else msgpack.unpackb(data))["reason"]
        assert why in reason, reason
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    assert "Traceback" not in err and "RecursionError" not in err
    refusals = [line for line in err.splitlines() if "refused: arm" in line]
    assert 1 <= len(refusals) <= 3, refusals                     # once per cause, not 30 times


def test_an_impostor_answering_the_steering_keys_is_caught(service, session, router):
    from viena.common.config import load_zenoh_config

    proc, latest, until = service
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as rogue:
        def late_reply(query):
            time.sleep(0.05)                                  # late: it would win consolidation
            query.reply(query.key_expr, b'{"status": "accepted", "lease": "rogue"}')
        q = rogue.declare_queryable(f"{KEY}/arm", late_reply)
        time.sleep(0.3)
        with pytest.raises(ConflictingReplies, match="2 processes answered steering/arm"):
            SteeringClient(session).arm()
        q.undeclare()


#: a flooding client: `viena bench faults`' flooder, setpoints signed with a wrong lease at this
#: rate, a process of its own as on the car (a thread of this process would take the GIL
#: from the drive's twin here, whose late answers then stop the steering for "no feedback
#: from the drive")
FLOOD_RATE_HZ = 10_000


def test_a_setpoint_flood_from_others_never_starves_the_owner(service, session, router, procs):
    proc, latest, until = service
    owner = SteeringClient(session)
    floods = [procs.python("-m", "benchmarks.faults", "--flood", router, "--flood-rate", FLOOD_RATE_HZ)
              for _ in range(2)]
    for flood in floods:                              # flooding before the owner arms: a
        wait_for_line(flood.stderr, "flooding", 30)   # process start outlasts the watchdog
    try:
        assert owner.arm()["status"] == "accepted"
        replies = []
        for k in range(60):                           # 3 s of the owner's stream at 20 Hz
            replies.append(owner.setpoint(0.2 * (k % 2)))
            time.sleep(0.05)
    finally:
        for flood in floods:
            flood.kill()
            flood.wait()
    assert all(r["status"] in ("accepted", "clamped") for r in replies), [r for r in replies
                                                                          if r["status"] == "rejected"][:3]
    assert until(lambda st: st["armed"] and st["trip"] == ""), latest
    owner.disarm()
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    flood_lines = [line for line in err.splitlines() if "not signed with the owner's lease" in line]
    assert len(flood_lines) <= 3, len(flood_lines)


def test_after_a_restart_the_service_says_why_the_drive_is_in_fault(service, session, twin, procs, router,
                                                                      tmp_path):
    from vienatest import wait_until

    from viena.services.steering.driver import ds402

    proc, latest, until = service
    lease = arm(session)
    for _ in range(10):
        session.put(f"{KEY}/setpoint", json.dumps(signed({"angle_deg": 2.0, "lease": lease})))
        time.sleep(0.02)
    proc.kill()                                  # the drive faults through its life guard
    proc.wait(5)
    assert wait_until(lambda: twin.twin.state == ds402.FAULT, 3.0)
    states = []
    sub = session.declare_subscriber(f"{KEY}/state", lambda s: states.append(s.payload.to_bytes()))
    procs.python("-m", "viena.services.steering.service", "--connect", router, "--config",
                 tmp_path / "steering.toml", "--interface", "slcan", "--channel", twin.url,
                 "--log-level", "WARNING")
    from viena.common.samples.steering import STATE
    assert wait_until(lambda: states and "Life Guard" in (STATE.decode(states[-1])["fault"] or ""), 20.0), \
        STATE.decode(states[-1]) if states else "no state"
    sub.undeclare()
