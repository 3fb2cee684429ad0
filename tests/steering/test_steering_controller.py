"""The steering controller against the twin (virtual CAN) on a simulated clock: calibration
at start, arm, steering, every way of stopping, and who may do what.

`steering_helpers.SimSteering` steps the controller and the twin one SYNC period at a time:
no threads of the controller's, no sleeps, the same frames in the same order every run. The
threaded runner itself is exercised through the slcan hub in test_steering_sim.py and as a
process in test_steering_service.py.
"""
from __future__ import annotations

import pytest
from steering_helpers import SimSteering as Steering

from viena.services.steering.driver import ds402
from viena.services.steering.model.trips import TripCause, trip


@pytest.fixture
def steering():
    s = Steering()
    s.ready()
    yield s
    s.close()


def test_start_up_calibrates_from_the_sweep_and_waits_disarmed(steering):
    st = steering.ctl.state()
    cal = steering.ctl.calibration
    assert st["phase"] == "ready" and not st["armed"] and st["calibration"]["state"] == "done"
    assert abs(cal.zero_qc - steering.twin.true_zero_qc) <= 600 and 95_000 <= cal.span_qc <= 96_500
    assert steering.twin.limits == cal.limits_qc()             # 0x607D written from the calibration
    assert st["ds402"] == ds402.SWITCH_ON_DISABLED and st["drive_heartbeat"] == "ok"


def test_an_armed_owner_steers_the_wheel(steering):
    lease = steering.arm()
    replies = steering.steer(lease, 8.0, 0.8)
    assert replies[0]["status"] == "clamped" and replies[0]["limits"] == ["slew"]
    assert replies[-1]["status"] == "accepted" and replies[-1]["target_deg"] == 8.0
    assert steering.run_until(lambda: abs(steering.wheel_deg() - 8.0) < 0.3, 1.0), steering.wheel_deg()
    st = steering.ctl.state()
    assert st["armed"] and st["owner"] != lease and len(st["owner"]) == 12
    assert st["ds402"] == ds402.OPERATION_ENABLED and abs(st["angle_deg"] - 8.0) < 0.5
    assert st["target_qc"] == round(steering.ctl.calibration.qc_of(8.0))


def test_silence_trips_the_watchdog_which_stops_then_powers_off(steering):
    lease = steering.arm()
    steering.steer(lease, 3.0, 0.3)
    steering.controlwords.clear()
    assert steering.run_until(lambda: not steering.ctl.envelope.armed, 1.5)
    assert steering.run_until(lambda: steering.twin.state == ds402.SWITCH_ON_DISABLED, 1.0)
    st = steering.ctl.state()
    assert st["watchdog"] == "tripped" and st["trip_cause"] == TripCause.WATCHDOG and not st["armed"]
    assert st["trip"].startswith(trip(TripCause.WATCHDOG).label)
    sent = [cw for i, cw in enumerate(steering.controlwords) if i == 0 or cw != steering.controlwords[i - 1]]
    assert sent[-3:] == [ds402.CW_ENABLE_OPERATION, ds402.CW_QUICK_STOP, ds402.CW_DISABLE_VOLTAGE]
    r = steering.request("setpoint", {"angle_deg": 3.0, "lease": lease})
    assert r["status"] == "rejected" and "arm again" in r["reason"]
    assert steering.arm() != lease


def test_estop_stops_whoever_asks(steering):
    steering.request("arm", {"arm": True})
    steering.controlwords.clear()
    r = steering.ctl.estop({"anything": "at all"})
    assert r["status"] == "accepted" and r["was_armed"]
    assert steering.run_until(lambda: ds402.CW_QUICK_STOP in steering.controlwords, 0.5)
    assert [cw for cw in steering.controlwords if cw != ds402.CW_ENABLE_OPERATION][0] == ds402.CW_QUICK_STOP
    assert steering.run_until(lambda: steering.twin.state == ds402.SWITCH_ON_DISABLED, 1.0)
    assert steering.ctl.state()["trip"] == "estop"
    assert steering.ctl.estop()["was_armed"] is False


def test_an_emcy_is_published_and_only_a_new_arm_resets_the_fault(steering):
    lease = steering.arm()
    steering.twin.inject_error(0x4210)
    assert steering.run_until(lambda: not steering.ctl.envelope.armed, 1.0)
    st = steering.ctl.state()
    assert st["fault"] == st["emcy"] == "EMCY 0x4210 Over Temperature" and "Over Temperature" in st["trip"]
    steering.run(0.3)
    assert steering.twin.state == ds402.FAULT                  # nothing resets it by itself
    assert steering.request("setpoint", {"angle_deg": 1.0, "lease": lease})["status"] == "rejected"
    new = steering.arm()                                       # the explicit re-arm: fault reset
    assert new != lease and steering.twin.state == ds402.OPERATION_ENABLED
    assert steering.ctl.state()["fault"] == ""


def test_a_following_error_is_published_and_needs_a_rearm():
    s = Steering(max_following_error_qc=300)                   # far tighter than a 30 deg/s ramp
    try:
        s.ready()
        lease = s.arm()
        s.steer(lease, 10.0, 0.3)
        assert s.run_until(lambda: "Following Error" in s.ctl.state()["fault"], 1.0), s.ctl.state()
        st = s.ctl.state()
        assert not st["armed"] and st["ds402"] == ds402.FAULT and "0x8611" in st["trip"]
        assert s.request("setpoint", {"angle_deg": 10.0, "lease": lease})["status"] == "rejected"
        s.arm()
        assert s.twin.state == ds402.OPERATION_ENABLED
    finally:
        s.close()


def test_a_second_client_cannot_take_the_wheel(steering):
    owner = steering.arm()
    assert steering.request("arm", {"arm": True})["reason"] == "armed by another client"
    assert steering.request("arm", {"arm": True, "lease": "guess"})["status"] == "rejected"
    r = steering.request("arm", {"arm": False, "lease": "guess"})
    assert r["status"] == "rejected" and "only the owner" in r["reason"]
    r = steering.request("setpoint", {"angle_deg": 5.0, "lease": "guess"})
    assert r["status"] == "rejected" and steering.ctl.envelope.target_deg != 5.0
    assert steering.request("arm", {"arm": True, "lease": owner})["status"] == "accepted"   # renewal
    assert steering.request("arm", {"arm": False, "lease": owner})["status"] == "accepted"
    assert not steering.ctl.envelope.armed


@pytest.mark.parametrize("payload, reason", [
    ({"arm": "yes"}, "true or false"),
    ({"arm": True, "force": True}, "unknown field 'force'"),
    ([1, 2], "expected a map"),
])
def test_malformed_arm_requests_are_rejected(steering, payload, reason):
    r = steering.request("arm", payload)
    assert r["status"] == "rejected" and reason in r["reason"]


def test_arming_is_refused_while_the_wheel_is_outside_the_envelope(steering):
    assert steering.run_until(lambda: not steering.twin.sweeping, 3.0)   # the person let go
    steering.twin.plant.x = 44_000.0                           # ~33 deg, past the 28 deg envelope
    steering.run(0.05)
    r = steering.request("arm", {"arm": True})
    assert r["status"] == "rejected" and "outside" in r["reason"]
    assert steering.twin.state == ds402.SWITCH_ON_DISABLED


def test_a_drive_reboot_drops_the_calibration_and_a_new_sweep_restores_it(steering):
    lease = steering.arm()
    old_zero = steering.ctl.calibration.zero_qc
    steering.twin.power_off()
    steering.twin.plant.x = 5_000.0                            # someone turned it while off
    steering.twin.power_on()
    assert steering.run_until(lambda: steering.ctl.phase not in ("ready", "armed"), 3.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed            # tripped by whatever it noticed first
    steering.ready(15.0)
    cal = steering.ctl.calibration
    assert cal.zero_qc != old_zero and abs(cal.zero_qc - steering.twin.true_zero_qc) <= 600, \
        (cal, steering.twin.true_zero_qc, old_zero)
    assert steering.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"


def test_calibration_requests(steering):
    r = steering.request("calibration", {})
    assert r["status"] == "accepted" and r["calibration"]["state"] == "done"
    r = steering.request("calibration", {"restart": True})
    assert r["calibration"]["state"] == "sweeping" and steering.ctl.phase == "calibrating"
    assert steering.request("arm", {"arm": True})["reason"].startswith("not ready")
    steering.run(0.1)
    r = steering.request("calibration", {"finish": True})     # nobody turned the wheel
    assert r["status"] == "rejected" and "not turned lock to lock" in r["reason"]
    assert steering.request("calibration", {"reset": 1})["status"] == "rejected"


def test_states_are_complete_and_keep_coming(steering):
    from viena.common.samples.steering import STATE
    n = len(steering.states)
    steering.run(0.3)
    fresh = steering.states[n:]
    assert len(fresh) >= 5
    for st in fresh:
        assert STATE.decode(STATE.encode(dict(st)))["phase"] == "ready"
    assert [s["seq"] for s in fresh] == sorted(s["seq"] for s in fresh)


def test_a_drive_that_drops_out_of_operational_is_configured_again(steering):
    """Another host (or a missed boot-up) sends the drive to pre-operational: PDOs stop."""
    lease = steering.arm()
    steering.ctl.drive.network.send_message(0, bytes([0x80, 1]))   # NMT enter pre-operational
    assert steering.run_until(lambda: steering.ctl.phase in ("connecting", "calibrating"), 2.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed
    assert steering.run_until(lambda: steering.twin.node.nmt.state == "OPERATIONAL", 2.0)
    assert steering.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"


def test_arming_right_after_an_estop_works(steering):
    steering.arm()
    steering.ctl.estop()
    lease = steering.arm()                                     # still quick-stopped: handled
    steering.run(0.2)                                          # past the estop's power-off time
    assert steering.ctl.envelope.armed and steering.twin.state == ds402.OPERATION_ENABLED
    assert steering.request("setpoint", {"angle_deg": 0.5, "lease": lease})["status"] != "rejected"


def test_a_drive_that_goes_silent_is_configured_and_calibrated_again_when_it_answers(steering):
    lease = steering.arm()
    steering.twin.power_off()                                  # no heartbeat, no answers
    assert steering.run_until(lambda: steering.ctl.phase == "connecting", 3.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed and steering.ctl.calibration is None
    steering.twin.power_on()
    steering.ready(15.0)
    assert steering.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"
