"""The steering core alone: no bus, no twin, no threads, no clock but the one each test moves.

Each test says what the drive reports on every SYNC period and checks the exact frames the
core asks for, at the exact simulated time: the DS402 steps of an arm and their deadlines,
the watchdog's quick stop and the power-off after the hold, supervision, reconnecting with
backoff, and the calibration's way from a sweep to the drive's limits.
"""
from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vienatest import signed

from viena.services.steering.driver import Emcy
from viena.services.steering.model import ds402
from viena.services.steering.model.actions import (
    Command,
    Configure,
    Connect,
    Cycle,
    DriveReading,
    Reply,
    SendTarget,
    WriteLimits,
)
from viena.services.steering.model.calibration import CalibrationSettings
from viena.services.steering.model.core import ControllerSettings, Phase, SteeringCore
from viena.services.steering.model.drive import NMT_OPERATIONAL, POSITION_MODE, Feedback
from viena.services.steering.model.requests import parse_request
from viena.services.steering.model.safety import Envelope
from viena.services.steering.model.speed import SpeedSettings
from viena.services.steering.model.state import sample
from viena.services.steering.model.trips import TripCause

STEERING = Path(__file__).resolve().parents[2] / "services/steering/model"
WALL_NS = 1_700_000_000_000_000_000
HOLD_S = ControllerSettings().quickstop_hold_s
SW = ds402.EPOS_STATUSWORD
LOCK_QC = 47_600


class Bench:
    """A SteeringCore on a simulated clock, told what the drive reports each period."""

    def __init__(self):
        self.t = 100.0
        self.core = SteeringCore(Envelope(speed_settings=SpeedSettings(speed_conservative_mps=0.0)), CalibrationSettings(sweep_settle_s=0.2))
        self.fb = Feedback(statusword=SW[ds402.SWITCH_ON_DISABLED], op_mode=POSITION_MODE, received_s=self.t)
        self.heartbeat_age_s = 0.05
        self.nmt_state: int | None = NMT_OPERATIONAL

    def reading(self) -> DriveReading:
        return DriveReading(self.fb, self.heartbeat_age_s, self.nmt_state)

    def tick(self, dt: float = 0.01, answered: bool = True, state: str | None = None,
             position_qc: int | None = None) -> list:
        """One SYNC period; the drive answers it (TPDO1 + TPDO2, in `state` at
        `position_qc` if given) unless `answered` is False."""
        self.t += dt
        if answered:
            changes = {"received_s": self.t, "count": self.fb.count + 2}
            if state is not None:
                changes["statusword"] = SW[state]
            if position_qc is not None:
                changes["position_qc"] = position_qc
            self.fb = replace(self.fb, **changes)
        return self.core.tick(self.t, self.reading())

    def ask(self, kind: str, payload, token="T") -> tuple[dict | None, list]:
        """A client's request; a setpoint signed with the lease it names, as a client sends it."""
        payload = signed(payload) if kind == "setpoint" else payload
        return self.core.handle(parse_request(kind, payload), self.t, WALL_NS, self.reading(), token)

    def configured(self) -> None:
        assert self.core.start(self.t) == [Connect()]
        assert self.core.connected(self.t) == [Configure()]
        assert self.core.configured(self.t) == []

    def sweep(self) -> list:
        """A person turns the wheel lock to lock and back; the actions of the period in
        which the core calls the sweep complete."""
        path = [*range(0, LOCK_QC, 2000), *range(LOCK_QC, -LOCK_QC, -2000), *range(-LOCK_QC, 1, 2000)]
        for qc in path + [0] * 40:
            actions = self.tick(position_qc=qc)
            if self.core.phase is not Phase.CALIBRATING:
                return actions
        raise AssertionError(f"the sweep did not complete: {self.core.recorder.status()}")

    def ready(self) -> Bench:
        self.configured()
        (write,) = [a for a in self.sweep() if isinstance(a, WriteLimits)]
        self.core.limits_written(self.t, write.calibration)
        assert self.core.phase is Phase.READY
        return self

    def armed(self) -> str:
        self.ready()
        assert self.ask("arm", {"arm": True}) == (None, [SendTarget(0, ds402.CW_SHUTDOWN)])
        self.tick(state=ds402.READY)
        (reply,) = [a for a in self.tick(state=ds402.OPERATION_ENABLED) if isinstance(a, Reply)]
        assert reply.answer["status"] == "accepted", reply
        return reply.answer["lease"]


def replies(actions: list) -> list[dict]:
    return [a.answer for a in actions if isinstance(a, Reply)]


# -- start-up and the calibration ---------------------------------------------------------
def test_start_up_connects_configures_and_writes_the_swept_limits_before_trusting_them():
    b = Bench()
    b.configured()
    assert b.core.phase is Phase.CALIBRATING
    assert b.tick() == [Cycle(None)]                          # the power stage stays off
    actions = b.sweep()
    (write,) = [a for a in actions if isinstance(a, WriteLimits)]
    assert write.calibration.zero_qc == 0 and write.calibration.span_qc == 2 * LOCK_QC
    assert b.core.phase is Phase.CHECKING and b.core.calibration is None
    assert b.ask("arm", {"arm": True})[0]["reason"] == "not ready: checking"
    assert b.core.limits_written(b.t, write.calibration) == []
    assert b.core.phase is Phase.READY and b.core.calibration is write.calibration
    assert b.core.envelope.range_deg == write.calibration.range_deg


def test_limits_the_drive_refuses_send_the_person_round_again():
    b = Bench()
    b.configured()
    (write,) = [a for a in b.sweep() if isinstance(a, WriteLimits)]
    b.core.limits_written(b.t, write.calibration, error="0x607D:1: no answer")
    assert b.core.phase is Phase.CALIBRATING and b.core.calibration is None
    assert b.core.recorder.problem == "drive refused the limits: 0x607D:1: no answer"


def test_limits_written_for_a_calibration_a_reboot_abandoned_are_ignored():
    b = Bench()
    b.configured()
    (write,) = [a for a in b.sweep() if isinstance(a, WriteLimits)]
    assert Configure() in b.core.on_bootup(b.t)
    assert b.core.limits_written(b.t, write.calibration) == []
    assert b.core.phase is Phase.CONNECTING and b.core.calibration is None


def test_a_link_that_will_not_open_is_retried_with_a_doubling_backoff():
    b = Bench()
    b.core.start(b.t)
    delays = []
    for _ in range(6):
        assert b.core.connected(b.t, error="no such adapter") == []
        since = b.t
        while Connect() not in b.tick(dt=0.25, answered=False):
            assert b.t - since < 10
        delays.append(b.t - since)
    assert delays == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0]
    b.core.connected(b.t)
    b.core.configured(b.t)                                     # success resets the backoff
    b.core.on_bootup(b.t)
    assert b.core.configured(b.t, error="SDO timeout") == []
    assert b.tick(dt=0.25, answered=False)[-1] == Cycle(None)  # the link is up: keep cycling
    assert b.tick(dt=0.25, answered=False) == [Connect()]      # then open it again, 0.5 s on
    assert not b.core.link_ok and b.core.phase is Phase.CONNECTING


# -- arming -------------------------------------------------------------------------------
def test_an_arm_walks_the_ds402_steps_one_period_each_then_answers():
    b = Bench().ready()
    answer, frames = b.ask("arm", {"arm": True}, token="me")
    assert answer is None and frames == [SendTarget(0, ds402.CW_SHUTDOWN)]
    assert b.tick() == [Cycle(None)]                          # not ready to switch on yet
    assert b.tick(state=ds402.READY, position_qc=-5) == [
        SendTarget(-5, ds402.CW_ENABLE_OPERATION), Cycle(None)]          # hold where it stands
    actions = b.tick(state=ds402.OPERATION_ENABLED)
    assert isinstance(actions[0], Reply) and actions[0].token == "me"
    answer = actions[0].answer
    assert answer["status"] == "accepted" and answer["target_deg"] == b.core.calibration.angle_deg(-5)
    assert actions[1] == Cycle(-5)                            # the target holds the wheel
    assert b.core.phase is Phase.ARMED and b.core.envelope.armed and b.core.arming is None


def test_a_faulted_drive_is_reset_by_an_arm_with_a_real_edge_of_bit_7():
    b = Bench().ready()
    b.fb = replace(b.fb, statusword=SW[ds402.FAULT])
    assert b.ask("arm", {"arm": True})[1] == [Command(ds402.CW_DISABLE_VOLTAGE)]
    assert b.tick(state=ds402.FAULT) == [Cycle(None)]         # one SYNC answered: not yet
    assert b.tick(state=ds402.FAULT) == [Command(ds402.CW_FAULT_RESET), Cycle(None)]
    assert b.tick(state=ds402.SWITCH_ON_DISABLED) == [
        Command(ds402.CW_DISABLE_VOLTAGE), SendTarget(0, ds402.CW_SHUTDOWN), Cycle(None)]
    assert b.tick(state=ds402.READY)[0] == SendTarget(0, ds402.CW_ENABLE_OPERATION)
    assert replies(b.tick(state=ds402.OPERATION_ENABLED))[0]["status"] == "accepted"


def test_a_quick_stopped_drive_is_powered_off_before_it_is_enabled_again():
    b = Bench().ready()
    b.fb = replace(b.fb, statusword=SW[ds402.QUICK_STOP_ACTIVE])
    assert b.ask("arm", {"arm": True})[1] == [Command(ds402.CW_DISABLE_VOLTAGE)]
    assert b.tick(state=ds402.SWITCH_ON_DISABLED)[0] == SendTarget(0, ds402.CW_SHUTDOWN)


def test_every_step_of_an_arm_has_a_deadline():
    b = Bench().ready()
    b.ask("arm", {"arm": True})
    assert replies(b.tick(dt=0.29)) == []                     # 300 ms for each step
    actions = b.tick(dt=0.02)
    assert actions[0] == Command(ds402.CW_DISABLE_VOLTAGE)
    assert replies(actions) == [{"status": "rejected", "reason": "drive did not become ready (SWITCH ON DISABLED)"}]
    assert b.core.arming is None and not b.core.envelope.armed and b.core.phase is Phase.READY


def test_a_stop_while_arming_answers_the_arm_and_stops_the_usual_way():
    b = Bench().ready()
    b.ask("arm", {"arm": True})
    answer, frames = b.ask("estop", {})
    assert answer["was_armed"] is False
    assert frames == [Reply("T", {"status": "rejected", "reason": "stopped while arming (estop)"}),
                      Command(ds402.CW_QUICK_STOP)]
    assert Command(ds402.CW_DISABLE_VOLTAGE) not in b.tick(dt=HOLD_S - 0.01)
    assert Command(ds402.CW_DISABLE_VOLTAGE) in b.tick(dt=0.02)


def test_one_arm_at_a_time_and_the_owner_renews_at_once():
    b = Bench()
    lease = b.armed()
    assert b.ask("arm", {"arm": True})[0]["reason"] == "armed by another client"
    answer, frames = b.ask("arm", {"arm": True, "lease": lease})
    assert answer["status"] == "accepted" and answer["lease"] == lease and frames == []
    b = Bench().ready()
    b.ask("arm", {"arm": True}, token="first")
    assert b.ask("arm", {"arm": True}, token="second")[0]["reason"] == "another client is arming"


def test_restarting_the_calibration_while_arming_abandons_the_arm():
    b = Bench().ready()
    b.ask("arm", {"arm": True})
    answer, frames = b.ask("calibration", {"restart": True})
    assert answer["calibration"]["state"] == "sweeping" and b.core.phase is Phase.CALIBRATING
    assert frames == [Reply("T", {"status": "rejected", "reason": "calibration restarted"}),
                      Command(ds402.CW_DISABLE_VOLTAGE)]


# -- steering and stopping ----------------------------------------------------------------
def test_a_setpoint_goes_to_the_drive_at_once():
    b = Bench()
    lease = b.armed()
    b.t += 0.1
    answer, frames = b.ask("setpoint", {"angle_deg": 1.0, "lease": lease})
    assert answer["status"] == "accepted" and answer["target_deg"] == 1.0
    assert frames == [SendTarget(round(b.core.calibration.qc_of(1.0)))]
    answer, frames = b.ask("setpoint", {"angle_deg": 1.0, "lease": "guess"})
    assert answer["status"] == "rejected" and frames == []


def test_an_estop_is_logged_with_its_sender_and_a_flood_of_them_once(caplog):
    b = Bench()
    b.armed()
    with caplog.at_level("WARNING", logger="viena.steering"):
        b.ask("estop", {"by": "bob"})
        for _ in range(1000):
            b.t += 0.005
            b.ask("estop", {"by": "bob"})
        b.ask("estop", {})
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("estop")]
    assert lines[0] == "estop: was armed, from 'bob' (as it says)"
    assert lines[1:] == ["estop: was not armed, from 'bob' (as it says)",
                         "estop: was not armed, from a sender that did not say who"], lines


def test_the_watchdog_quick_stops_on_time_and_powers_off_after_the_hold():
    b = Bench()
    b.armed()
    assert Command(ds402.CW_QUICK_STOP) not in b.tick(dt=0.49)
    actions = b.tick(dt=0.02)
    assert actions[0] == Command(ds402.CW_QUICK_STOP) and b.core.envelope.trip_cause is TripCause.WATCHDOG
    assert not b.core.envelope.armed and b.core.phase is Phase.READY
    assert actions[1] == Cycle(None)                          # no target once disarmed
    assert Command(ds402.CW_DISABLE_VOLTAGE) not in b.tick(dt=HOLD_S - 0.01)
    assert b.tick(dt=0.02) == [Command(ds402.CW_DISABLE_VOLTAGE), Cycle(None)]


def test_a_setpoint_after_the_deadline_finds_the_wheel_given_up():
    b = Bench()
    lease = b.armed()
    b.t += 0.6                                                # no tick came (a starved host)
    answer, frames = b.ask("setpoint", {"angle_deg": 1.0, "lease": lease})
    assert answer["status"] == "rejected" and "arm again" in answer["reason"]
    assert frames == [Command(ds402.CW_QUICK_STOP)]


def test_a_lost_heartbeat_stops_the_wheel_and_a_silent_drive_is_configured_again():
    b = Bench()
    b.armed()
    b.heartbeat_age_s = 0.34
    assert Command(ds402.CW_QUICK_STOP) not in b.tick()
    b.heartbeat_age_s = 0.36
    assert b.tick()[0] == Command(ds402.CW_QUICK_STOP) and b.core.envelope.tripped == "drive heartbeat lost"
    assert b.core.envelope.trip_cause is TripCause.DRIVE_HEARTBEAT
    assert sample(b.core, b.t, WALL_NS, b.reading(), 1)["drive_heartbeat"] == "lost"
    b.heartbeat_age_s = 0.99
    assert Configure() not in b.tick()
    b.heartbeat_age_s = 1.01
    assert Configure() in b.tick()
    assert b.core.phase is Phase.CONNECTING and b.core.calibration is None


def test_a_drive_that_says_it_is_not_operational_is_configured_again():
    b = Bench().ready()
    b.nmt_state = 0x7F                                        # pre-operational
    assert Configure() not in b.tick()
    assert Configure() not in b.tick(dt=0.3)
    assert Configure() in b.tick(dt=0.02)


def test_feedback_that_stops_while_armed_stops_the_wheel():
    b = Bench()
    b.armed()
    assert Command(ds402.CW_QUICK_STOP) not in b.tick(dt=0.19, answered=False)
    assert b.tick(dt=0.02, answered=False)[0] == Command(ds402.CW_QUICK_STOP)
    assert b.core.envelope.tripped == "no feedback from the drive"
    assert b.core.envelope.trip_cause is TripCause.FEEDBACK_TIMEOUT


def test_an_emcy_stops_the_wheel_and_names_the_fault():
    b = Bench()
    b.armed()
    assert b.core.on_emcy(b.t, Emcy(0x4210, 0x09)) == [Command(ds402.CW_QUICK_STOP)]
    assert b.core.fault == "EMCY 0x4210 Over Temperature" and "Over Temperature" in b.core.envelope.tripped
    assert b.core.envelope.tripped == "drive EMCY 0x4210 Over Temperature"
    assert b.core.envelope.trip_cause is TripCause.DRIVE_FAULT
    assert b.core.on_emcy(b.t, Emcy(0, 0)) == [] and b.core.fault == ""


def test_the_drives_life_guard_is_its_own_cause_with_the_same_text():
    b = Bench()
    b.armed()
    assert b.core.on_emcy(b.t, Emcy(0x8130, 0x11)) == [Command(ds402.CW_QUICK_STOP)]
    assert b.core.envelope.tripped == "drive EMCY 0x8130 CAN Life Guard Error"
    assert sample(b.core, b.t, WALL_NS, b.reading(), 1)["trip_cause"] == TripCause.LIFE_GUARD == "life_guard"


def test_a_lost_link_trips_sends_nothing_and_reconnects():
    b = Bench()
    b.armed()
    assert b.core.link_lost(b.t, "adapter unplugged") == [Connect()]
    assert b.core.envelope.tripped == "CAN link lost: adapter unplugged" and b.core.phase is Phase.CONNECTING
    assert b.core.envelope.trip_cause is TripCause.LINK_LOST
    assert b.tick() == []                                     # nothing goes on a link that is down


def test_stopping_the_service_stops_the_wheel_and_says_how_long_to_hold():
    b = Bench()
    b.armed()
    assert b.core.shutdown(b.t) == ([Command(ds402.CW_QUICK_STOP)], HOLD_S)
    assert b.core.power_off() == [Command(ds402.CW_DISABLE_VOLTAGE)]
    assert Bench().ready().core.shutdown(b.t)[1] == 0.0       # nothing to hold


# -- purity -------------------------------------------------------------------------------
def test_the_core_reads_no_clock_starts_no_thread_and_touches_no_bus():
    forbidden = {"time", "threading", "queue", "asyncio", "socket", "serial", "can", "canopen", "zenoh"}
    for name in ("core.py", "arming.py", "actions.py", "requests.py", "safety.py", "supervision.py",
                 "calibration.py", "state.py"):
        tree = ast.parse((STEERING / name).read_text())
        modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        modules |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        assert not {m.split(".")[0] for m in modules} & forbidden, (name, modules)


# -- properties ---------------------------------------------------------------------------
class ObedientDrive:
    """Just enough DS402 for the core's frames to take effect: it does as it is told and
    its wheel follows the target while enabled (the script may still force any state)."""

    def __init__(self):
        self.state, self.controlword, self.position_qc = ds402.SWITCH_ON_DISABLED, 0, 0

    def hear(self, actions: list) -> None:
        for a in actions:
            if isinstance(a, (SendTarget, Cycle)) and a.target_qc is not None and self.state == ds402.OPERATION_ENABLED:
                self.position_qc = a.target_qc
            if getattr(a, "controlword", None) is not None:
                self._obey(a.controlword)

    def _obey(self, cw: int) -> None:
        previous, self.controlword = self.controlword, cw
        s = self.state
        if s == ds402.FAULT:
            if cw & 0x80 and not previous & 0x80:
                self.state = ds402.SWITCH_ON_DISABLED
        elif cw & 0x02 == 0:
            self.state = ds402.SWITCH_ON_DISABLED
        elif cw & 0x06 == 0x02:
            self.state = ds402.QUICK_STOP_ACTIVE if s == ds402.OPERATION_ENABLED else ds402.SWITCH_ON_DISABLED
        elif cw & 0x07 == 0x06 and s in (ds402.SWITCH_ON_DISABLED, ds402.OPERATION_ENABLED):
            self.state = ds402.READY
        elif cw & 0x0F == 0x0F and s in (ds402.READY, ds402.QUICK_STOP_ACTIVE):
            self.state = ds402.OPERATION_ENABLED


STATES = [ds402.SWITCH_ON_DISABLED, ds402.READY, ds402.OPERATION_ENABLED, ds402.QUICK_STOP_ACTIVE, ds402.FAULT]

events = st.one_of(
    st.tuples(st.just("tick"), st.floats(0.001, 0.3), st.booleans()),
    st.tuples(st.just("ticks"), st.booleans(), st.integers(1, 60)),       # False: the drive is quiet
    st.tuples(st.just("steer"), st.floats(-40, 40), st.integers(1, 100)),     # the owner streams
    st.tuples(st.just("force"), st.sampled_from(STATES), st.integers(-60_000, 60_000)),
    st.tuples(st.just("arm"), st.sampled_from([None, "OWNER", "guess"])),
    st.tuples(st.just("disarm"), st.sampled_from(["OWNER", "guess"])),
    st.tuples(st.just("setpoint"), st.floats(-100, 100), st.sampled_from(["OWNER", "OWNER", "guess"])),
    st.tuples(st.just("estop")),
    st.tuples(st.just("emcy"), st.sampled_from([0x0000, 0x4210, 0x8611])),
    st.tuples(st.just("heartbeat"), st.one_of(st.just(0.05), st.floats(0.0, 2.0))),
    st.tuples(st.just("bootup")),
    st.tuples(st.just("link_lost")),
)


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(events, min_size=1, max_size=60))
def test_for_any_drive_and_any_client_the_wheel_moves_only_by_an_arm_and_inside_the_range(script):
    """Starting armed, whatever the drive reports and whoever asks: only an arm in progress
    enables the drive; a target reaches it only while armed, inside the calibrated range;
    every estop, and every loss of the arm, sends a quick stop, followed by a power-off once
    the hold is over; after a tick, armed means a drive heard within its heartbeat timeout,
    fresh feedback in operation enabled, and a valid setpoint within the watchdog; an EMCY
    fault disarms at once."""
    b = Bench()
    owner = b.armed()
    core, env, drive = b.core, b.core.envelope, ObedientDrive()
    drive.state = ds402.OPERATION_ENABLED
    last_valid = b.t
    off_due: float | None = None            # a quick stop was sent: power off by then

    def allowed_qc(cal) -> tuple[float, float]:
        lo, hi = env.allowed_deg
        qc = (cal.qc_of(lo), cal.qc_of(hi))
        return min(qc) - 1, max(qc) + 1

    def check(actions, arming_before: bool, armed_before: bool, cal, tick: bool) -> None:
        nonlocal off_due
        cws = [a.controlword for a in actions if getattr(a, "controlword", None) is not None]
        if armed_before and not env.armed and core.link_ok:
            assert ds402.CW_QUICK_STOP in cws, f"disarmed without a quick stop: {actions}"
        for a in actions:
            cw = getattr(a, "controlword", None)
            if cw in (ds402.CW_ENABLE_OPERATION, ds402.CW_SHUTDOWN, ds402.CW_FAULT_RESET):
                assert arming_before or core.arming is not None, f"{a} outside an arm"
            target = a.target_qc if isinstance(a, (Cycle, SendTarget)) and cw is None else None
            if target is not None:
                assert env.armed, f"{a} while disarmed"
                lo, hi = allowed_qc(cal)
                assert lo <= target <= hi, f"{a} outside {lo}..{hi}"
            if cw == ds402.CW_QUICK_STOP:
                off_due = b.t + HOLD_S
            elif cw == ds402.CW_DISABLE_VOLTAGE or core.arming is not None or not core.link_ok:
                off_due = None
        if tick and off_due is not None and b.t >= off_due + 1e-9 and core.link_ok:
            raise AssertionError(f"no power-off {b.t - off_due + HOLD_S:.3f} s after a quick stop")

    def tick(dt: float, answered: bool = True) -> list:
        was_armed, since = env.armed, last_valid
        actions = b.tick(dt, answered, drive.state, drive.position_qc)
        if was_armed and since is not None and b.t - since > env.settings.watchdog_s:
            assert not env.armed, "armed past the watchdog"
        if env.armed:
            assert b.heartbeat_age_s <= core.drive.drive_heartbeat_timeout_s, "armed without a heartbeat"
            assert b.t - b.fb.received_s <= core.settings.feedback_timeout_s, "armed without feedback"
            assert b.fb.state == ds402.OPERATION_ENABLED, f"armed with the drive in {b.fb.state}"
        return actions

    for event in script:
        kind = event[0]
        for _ in range(event[-1] if kind in ("ticks", "steer") else 1):
            arming_before, armed_before, cal = core.arming is not None, env.armed, core.calibration
            if kind == "tick":
                actions = tick(event[1], event[2])
            elif kind == "ticks":
                actions = tick(0.01, event[1])
            elif kind == "steer":
                answer, sent = b.ask("setpoint", {"angle_deg": event[1], "lease": owner})
                if answer["status"] != "rejected":
                    last_valid = b.t
                check(sent, arming_before, armed_before, cal, False)
                drive.hear(sent)
                arming_before, armed_before = core.arming is not None, env.armed
                actions = tick(0.01)
            elif kind == "force":
                drive.state, drive.position_qc = event[1], event[2]
                actions = []
            elif kind in ("arm", "disarm", "setpoint"):
                lease = owner if event[-1] == "OWNER" else event[-1]
                payload = {"angle_deg": event[1], "lease": lease} if kind == "setpoint" \
                    else {"arm": kind == "arm", "lease": lease}
                answer, actions = b.ask("setpoint" if kind == "setpoint" else "arm", payload)
                if answer is not None and answer["status"] != "rejected" and kind != "disarm":
                    last_valid = b.t
            elif kind == "estop":
                actions = b.ask("estop", {})[1]
                assert not core.link_ok or Command(ds402.CW_QUICK_STOP) in actions
            elif kind == "emcy":
                actions = core.on_emcy(b.t, Emcy(event[1], 0))
                assert event[1] == 0 or not env.armed
            elif kind == "heartbeat":
                b.heartbeat_age_s = event[1]
                actions = []
            elif kind == "bootup":
                actions = core.on_bootup(b.t)
            else:
                actions = core.link_lost(b.t, "gone")
            for answer in replies(actions):
                if answer["status"] == "accepted" and "lease" in answer:
                    owner, last_valid = answer["lease"], b.t
            check(actions, arming_before, armed_before, cal, kind in ("tick", "ticks"))
            drive.hear(actions)
            for job in [a for a in actions if isinstance(a, (Connect, Configure))]:   # the runner's part
                followed = core.connected(b.t) if isinstance(job, Connect) else core.configured(b.t)
                check(followed, core.arming is not None, env.armed, cal, False)
