"""The steering controller with its real threads against the running twin (virtual CAN):
calibration at start, arm, steering, every way of stopping, and who may do what."""
from __future__ import annotations

import itertools
import math
import time

import canopen
import pytest

from viena.common.service import wait_until
from viena.services.steering.calibration import CalibrationSettings
from viena.services.steering.controller import ControllerSettings, SteeringController
from viena.services.steering.driver import DriveSettings, EposDrive, ds402
from viena.services.steering.safety import Envelope
from viena.services.steering.simulator.twin import EposTwin, TwinSettings

_n = itertools.count()
FAST_SWEEP = TwinSettings(sweep_speed_qc_s=400_000, sweep_delay_s=0.1, sweep_hold_s=0.05)


class Steering:
    def __init__(self, twin_settings=FAST_SWEEP, **drive_kw):
        channel = f"controller-test-{next(_n)}"
        self.net = canopen.Network()
        self.net.NOTIFIER_CYCLE = 0.1
        self.net.connect(interface="virtual", channel=channel)
        self.twin = EposTwin(self.net, twin_settings).start()
        self.controlwords: list[int] = []
        self.net.subscribe(0x201, lambda _id, data, _t: self.controlwords.append(int.from_bytes(data[:2], "little")))
        self.states: list[dict] = []
        self.ctl = SteeringController(
            EposDrive(DriveSettings(interface="virtual", channel=channel, **drive_kw)), Envelope(),
            CalibrationSettings(settle_s=0.2), ControllerSettings(), on_state=self.states.append)
        self.ctl.start()

    def ready(self, timeout=10.0):
        assert wait_until(lambda: self.ctl.phase == "ready", timeout), self.ctl.state()

    def arm(self) -> str:
        r = self.ctl.request("arm", {"arm": True})
        assert r["status"] == "accepted", r
        return r["lease"]

    def steer(self, lease, angle, seconds, rate=50.0):
        replies = []
        for _ in range(int(seconds * rate)):
            replies.append(self.ctl.request("setpoint", {"angle_deg": angle, "lease": lease}))
            time.sleep(1 / rate)
        return replies

    def wheel_deg(self) -> float:
        return math.degrees(self.twin.wheel_angle_rad())

    def close(self):
        self.ctl.stop()
        self.twin.stop()
        self.net.disconnect()


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
    assert wait_until(lambda: abs(steering.wheel_deg() - 8.0) < 0.3, 1.0), steering.wheel_deg()
    st = steering.ctl.state()
    assert st["armed"] and st["owner"] != lease and len(st["owner"]) == 12
    assert st["ds402"] == ds402.OPERATION_ENABLED and abs(st["angle_deg"] - 8.0) < 0.5
    assert st["target_qc"] == round(steering.ctl.calibration.qc_of(8.0))


def test_silence_trips_the_watchdog_which_stops_then_powers_off(steering):
    lease = steering.arm()
    steering.steer(lease, 3.0, 0.3)
    steering.controlwords.clear()
    assert wait_until(lambda: not steering.ctl.envelope.armed, 1.5)
    assert wait_until(lambda: steering.twin.state == ds402.SWITCH_ON_DISABLED, 1.0)
    st = steering.ctl.state()
    assert st["watchdog"] == "tripped" and st["trip"].startswith("watchdog") and not st["armed"]
    sent = [cw for i, cw in enumerate(steering.controlwords) if i == 0 or cw != steering.controlwords[i - 1]]
    assert sent[-3:] == [ds402.CW_ENABLE_OPERATION, ds402.CW_QUICK_STOP, ds402.CW_DISABLE_VOLTAGE]
    r = steering.ctl.request("setpoint", {"angle_deg": 3.0, "lease": lease})
    assert r["status"] == "rejected" and "arm again" in r["reason"]
    assert steering.arm() != lease


def test_estop_stops_whoever_asks(steering):
    steering.ctl.request("arm", {"arm": True})
    steering.controlwords.clear()
    r = steering.ctl.estop({"anything": "at all"})
    assert r["status"] == "accepted" and r["was_armed"]
    assert wait_until(lambda: ds402.CW_QUICK_STOP in steering.controlwords, 0.5)
    assert [cw for cw in steering.controlwords if cw != ds402.CW_ENABLE_OPERATION][0] == ds402.CW_QUICK_STOP
    assert wait_until(lambda: steering.twin.state == ds402.SWITCH_ON_DISABLED, 1.0)
    assert steering.ctl.state()["trip"] == "estop"
    assert steering.ctl.estop()["was_armed"] is False


def test_an_emcy_is_published_and_only_a_new_arm_resets_the_fault(steering):
    lease = steering.arm()
    steering.twin.inject_error(0x4210)
    assert wait_until(lambda: not steering.ctl.envelope.armed, 1.0)
    st = steering.ctl.state()
    assert st["fault"] == st["emcy"] == "EMCY 0x4210 Over Temperature" and "Over Temperature" in st["trip"]
    time.sleep(0.3)
    assert steering.twin.state == ds402.FAULT                  # nothing resets it by itself
    assert steering.ctl.request("setpoint", {"angle_deg": 1.0, "lease": lease})["status"] == "rejected"
    new = steering.arm()                                       # the explicit re-arm: fault reset
    assert new != lease and steering.twin.state == ds402.OPERATION_ENABLED
    assert steering.ctl.state()["fault"] == ""


def test_a_following_error_is_published_and_needs_a_rearm():
    s = Steering(max_following_error_qc=300)                   # far tighter than a 30 deg/s ramp
    try:
        s.ready()
        lease = s.arm()
        s.steer(lease, 10.0, 0.3)
        assert wait_until(lambda: "Following Error" in s.ctl.state()["fault"], 1.0), s.ctl.state()
        st = s.ctl.state()
        assert not st["armed"] and st["ds402"] == ds402.FAULT and "0x8611" in st["trip"]
        assert s.ctl.request("setpoint", {"angle_deg": 10.0, "lease": lease})["status"] == "rejected"
        s.arm()
        assert s.twin.state == ds402.OPERATION_ENABLED
    finally:
        s.close()


def test_a_second_client_cannot_take_the_wheel(steering):
    owner = steering.arm()
    assert steering.ctl.request("arm", {"arm": True})["reason"] == "armed by another client"
    assert steering.ctl.request("arm", {"arm": True, "lease": "guess"})["status"] == "rejected"
    r = steering.ctl.request("arm", {"arm": False, "lease": "guess"})
    assert r["status"] == "rejected" and "only the owner" in r["reason"]
    r = steering.ctl.request("setpoint", {"angle_deg": 5.0, "lease": "guess"})
    assert r["status"] == "rejected" and steering.ctl.envelope.target_deg != 5.0
    assert steering.ctl.request("arm", {"arm": True, "lease": owner})["status"] == "accepted"   # renewal
    assert steering.ctl.request("arm", {"arm": False, "lease": owner})["status"] == "accepted"
    assert not steering.ctl.envelope.armed


@pytest.mark.parametrize("payload, reason", [
    ({"arm": "yes"}, "true or false"),
    ({"arm": True, "force": True}, "unknown field 'force'"),
    ([1, 2], "expected a map"),
])
def test_malformed_arm_requests_are_rejected(steering, payload, reason):
    r = steering.ctl.request("arm", payload)
    assert r["status"] == "rejected" and reason in r["reason"]


def test_arming_is_refused_while_the_wheel_is_outside_the_envelope(steering):
    steering.twin.plant.x = 44_000.0                           # ~33 deg, past the 28 deg envelope
    time.sleep(0.05)
    r = steering.ctl.request("arm", {"arm": True})
    assert r["status"] == "rejected" and "outside" in r["reason"]
    assert steering.twin.state == ds402.SWITCH_ON_DISABLED


def test_a_drive_reboot_drops_the_calibration_and_a_new_sweep_restores_it(steering):
    lease = steering.arm()
    old_zero = steering.ctl.calibration.zero_qc
    steering.twin.power_off()
    steering.twin.plant.x = 5_000.0                            # someone turned it while off
    steering.twin.power_on()
    assert wait_until(lambda: steering.ctl.phase not in ("ready", "armed"), 3.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed            # tripped by whatever it noticed first
    steering.ready(15.0)
    cal = steering.ctl.calibration
    assert cal.zero_qc != old_zero and abs(cal.zero_qc - steering.twin.true_zero_qc) <= 600, \
        (cal, steering.twin.true_zero_qc, old_zero)
    assert steering.ctl.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"


def test_calibration_requests(steering):
    r = steering.ctl.request("calibration", {})
    assert r["status"] == "accepted" and r["calibration"]["state"] == "done"
    r = steering.ctl.request("calibration", {"restart": True})
    assert r["calibration"]["state"] == "sweeping" and steering.ctl.phase == "calibrating"
    assert steering.ctl.request("arm", {"arm": True})["reason"].startswith("not ready")
    time.sleep(0.1)
    r = steering.ctl.request("calibration", {"finish": True})     # nobody turned the wheel
    assert r["status"] == "rejected" and "not turned lock to lock" in r["reason"]
    assert steering.ctl.request("calibration", {"reset": 1})["status"] == "rejected"


def test_states_are_complete_and_keep_coming(steering):
    from viena.services.steering.state import STATE
    n = len(steering.states)
    time.sleep(0.3)
    fresh = steering.states[n:]
    assert len(fresh) >= 5
    for st in fresh:
        assert STATE.decode(STATE.encode(dict(st)))["phase"] == "ready"
    assert [s["seq"] for s in fresh] == sorted(s["seq"] for s in fresh)


def test_a_drive_that_drops_out_of_operational_is_configured_again(steering):
    """Another host (or a missed boot-up) sends the drive to pre-operational: PDOs stop."""
    lease = steering.arm()
    steering.ctl.drive.network.send_message(0, bytes([0x80, 1]))   # NMT enter pre-operational
    assert wait_until(lambda: steering.ctl.phase in ("connecting", "calibrating"), 2.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed
    assert wait_until(lambda: steering.twin.node.nmt.state == "OPERATIONAL", 2.0)
    assert steering.ctl.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"


def test_arming_right_after_an_estop_works(steering):
    steering.arm()
    steering.ctl.estop()
    lease = steering.arm()                                     # still quick-stopped: handled
    time.sleep(0.2)                                            # past the estop's power-off time
    assert steering.ctl.envelope.armed and steering.twin.state == ds402.OPERATION_ENABLED
    assert steering.ctl.request("setpoint", {"angle_deg": 0.5, "lease": lease})["status"] != "rejected"


def test_a_drive_that_goes_silent_is_configured_and_calibrated_again_when_it_answers(steering):
    lease = steering.arm()
    steering.twin.power_off()                                  # no heartbeat, no answers
    assert wait_until(lambda: steering.ctl.phase == "connecting", 3.0), steering.ctl.state()
    assert not steering.ctl.envelope.armed and steering.ctl.calibration is None
    steering.twin.power_on()
    steering.ready(15.0)
    assert steering.ctl.request("setpoint", {"angle_deg": 0.0, "lease": lease})["status"] == "rejected"
