"""`viena-steering` as a process on zenoh, driving the twin through the slcan hub: the
query API in JSON and msgpack, puts, the state stream, and the drive stopping by itself
when the service dies."""
from __future__ import annotations

import json
import queue
import signal
import time

import msgpack
import pytest
from vienatest import fast_sweeping_twin, signed, steering_on, wait_until

from viena.common.samples.steering import STATE
from viena.services.steering.driver import ds402
from viena.services.steering.driver.emcy import LIFE_GUARD_ERROR

pytestmark = pytest.mark.slow  # the service as a process

KEY = "viena/elettra/steering"


@pytest.fixture
def twin():
    dev = fast_sweeping_twin()
    yield dev
    dev.stop()


@pytest.fixture
def service(procs, router, session, twin, tmp_path):
    proc, ready = steering_on(procs, router, twin, tmp_path / "steering.toml")
    states: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(f"{KEY}/state", lambda s: states.put(s))
    latest = {}

    def until(condition, timeout=2.0) -> bool:
        """Wait for the newest state to satisfy condition(state)."""
        def check():
            while not states.empty():
                sample = states.get()
                latest.update(STATE.decode(sample.payload.to_bytes()), encoding=str(sample.encoding))
            return bool(latest) and condition(latest)
        return wait_until(check, timeout)
    assert until(ready, 20.0), (latest, proc.poll())
    yield proc, latest, until
    sub.undeclare()


#: the router lets one query per client and command key through every 50 ms (5 ms for
#: setpoints; compose/zenoh/router.json5), and drops one asked sooner unanswered: these
#: tests ask back to back, so they keep twice that apart
QUERY_GAP_S = {"setpoint": 0.01}
_asked: dict[str, float] = {}


def get(session, name, payload: bytes):
    time.sleep(max(0.0, _asked.get(name, 0.0) + QUERY_GAP_S.get(name, 0.1) - time.monotonic()))
    _asked[name] = time.monotonic()
    replies = list(session.get(f"{KEY}/{name}", payload=payload, timeout=10.0))   # a busy machine answers late
    assert len(replies) == 1 and replies[0].ok is not None
    return replies[0].ok.payload.to_bytes(), str(replies[0].ok.encoding)


def test_the_zenoh_api_in_json_and_msgpack(service, session, twin):
    proc, latest, until = service
    assert latest["encoding"] == STATE.encoding and latest["calibration"]["state"] == "done"
    data, enc = get(session, "arm", b'{"arm": true}')
    assert enc == "application/json"
    lease = json.loads(data)["lease"]
    data, enc = get(session, "setpoint", msgpack.packb(signed({"angle_deg": 4.0, "lease": lease})))
    assert enc.startswith("application/msgpack")
    reply = msgpack.unpackb(data)
    assert reply["status"] == "clamped" and reply["limits"] == ["slew"] and reply["goal_deg"] == 4.0
    for _ in range(25):                          # puts: no reply, same treatment
        session.put(f"{KEY}/setpoint", json.dumps(signed({"angle_deg": 4.0, "lease": lease})))
        time.sleep(0.02)
    assert until(lambda st: st["angle_deg"] is not None and abs(st["angle_deg"] - 4.0) < 0.3), latest
    assert latest["armed"] and latest["target_deg"] == 4.0 and latest["ds402"] == ds402.OPERATION_ENABLED
    data, _ = get(session, "setpoint", json.dumps(signed({"angle_deg": "left", "lease": lease})).encode())
    assert json.loads(data)["status"] == "rejected" and "must be a number" in json.loads(data)["reason"]
    data, _ = get(session, "setpoint", b"{not json")
    assert json.loads(data)["status"] == "rejected" and "JSON" in json.loads(data)["reason"]
    session.put(f"{KEY}/estop", b"{}")
    assert until(lambda st: not st["armed"] and st["trip"] == "estop"), latest
    data, _ = get(session, "calibration", b"")
    assert msgpack.unpackb(data)["calibration"]["state"] == "done"


def test_the_client_arms_holds_an_angle_and_disarms(service, session, twin):
    from viena.services.steering.client import SteeringClient
    proc, latest, until = service
    client = SteeringClient(session)
    assert client.arm()["status"] == "accepted"
    assert client.hold(-3.0, 0.6)["status"] in ("accepted", "clamped")
    assert until(lambda st: st["armed"] and st["target_deg"] == -3.0)
    assert client.disarm()["status"] == "accepted"
    assert until(lambda st: not st["armed"] and st["trip"] == "")


def test_killing_the_service_makes_the_drive_fault_through_its_heartbeat_consumer(service, session, twin):
    proc, latest, until = service
    lease = json.loads(get(session, "arm", b'{"arm": true}')[0])["lease"]
    for _ in range(10):
        session.put(f"{KEY}/setpoint", json.dumps(signed({"angle_deg": 2.0, "lease": lease})))
        time.sleep(0.02)
    assert twin.twin.state == ds402.OPERATION_ENABLED
    proc.send_signal(signal.SIGKILL)                  # no goodbye: only the heartbeat stops
    proc.wait(5)
    assert wait_until(lambda: LIFE_GUARD_ERROR in twin.twin.errors, 2.0), twin.twin.errors
    assert wait_until(lambda: twin.twin.state == ds402.FAULT, 1.0)
    assert twin.twin.emcy_sent[-1] == LIFE_GUARD_ERROR
