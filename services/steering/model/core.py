"""The steering core: every decision the steering service makes, as a function of its state,
one event and the time it happened.

    core = SteeringCore(Envelope(), CalibrationSettings(), ControllerSettings(), DriveSettings())
    core.start(now)                                  -> [Connect()]
    core.tick(now, reading)                          -> [..., Cycle(target_qc)]  every SYNC period
    core.handle(request, now, wall_ns, reading, token) -> (answer or None, actions)
    core.on_emcy(now, emcy), core.on_bootup(now), core.link_lost(now, error)
    core.connected / configured / limits_written(now, ...)   outcomes of the blocking jobs
    state.sample(core, now, wall_ns, reading, seq)            what it publishes

It reads no clock, starts no thread, never waits and never touches the bus: it is given a
`DriveReading` and returns `actions` (frames to send, blocking jobs, late replies) for the
runner (`controller.SteeringController`) to carry out. Every path is therefore testable on
a simulated clock, one event at a time.

Phases: connecting -> calibrating (the person's sweep) -> checking (limits written to the
drive) -> ready <-> armed. Every stop (a disarm, or a trip: model/trips.py) is the same:
quick stop now, so the drive halts and holds the wheel, then power off after
`quickstop_hold_s`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

from viena.common.log import Throttled
from viena.common.settings import setting
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
from viena.services.steering.model.arming import ArmSequence
from viena.services.steering.model.calibration import (
    Calibration,
    CalibrationRefused,
    CalibrationSettings,
    SweepRecorder,
)
from viena.services.steering.model.drive import POSITION_MODE, DriveSettings, Feedback
from viena.services.steering.model.requests import (
    Arm,
    BadSetpoint,
    CalibrationRequest,
    Disarm,
    Estop,
    Refused,
    Request,
    Setpoint,
)
from viena.services.steering.model.safety import ACCEPTED, REJECTED, Envelope
from viena.services.steering.model.supervision import Backoff, DriveWatch
from viena.services.steering.model.trips import TripCause

if TYPE_CHECKING:                     # the driver's package loads the CAN stack
    from viena.services.steering.driver.emcy import Emcy

#: the EMCY the drive sends when the host's heartbeat stops (driver/emcy.py LIFE_GUARD_ERROR)
LIFE_GUARD_ERROR = 0x8130

log = logging.getLogger("viena.steering")


class Phase(StrEnum):
    CONNECTING = "connecting"      # opening the link, configuring the drive
    CALIBRATING = "calibrating"    # power stage off, recording the person's sweep
    CHECKING = "checking"          # writing the calibrated limits to the drive
    READY = "ready"                # calibrated, disarmed
    ARMED = "armed"                # an owner steers


@dataclass(frozen=True)
class ControllerSettings:
    quickstop_hold_s: float = setting(0.1, "quick stop, hold this long, then power off")
    feedback_timeout_s: float = setting(0.2, "no TPDO for this long while armed: trip")
    state_rate_hz: float = setting(50.0, "steering states published per second")
    arm_step_timeout_s: float = setting(0.3, "longest wait for each DS402 step of an arm")
    silent_drive_s: float = setting(1.0, "no heartbeat this long: configure (and calibrate) again")
    reconnect_min_s: float = setting(0.5, "first wait before reopening a lost CAN link")
    reconnect_max_s: float = setting(5.0, "longest wait between attempts to reopen it")


class SteeringCore:
    """The phase machine, the drive's supervision and the stops around the envelope."""

    def __init__(self, envelope: Envelope, calibration: CalibrationSettings = CalibrationSettings(),
                 settings: ControllerSettings = ControllerSettings(),
                 drive: DriveSettings | None = None):
        self.envelope = envelope
        self.settings = settings
        self.drive = drive = drive or DriveSettings()
        self.phase = Phase.CONNECTING
        self.calibration: Calibration | None = None
        self.recorder = SweepRecorder(calibration)
        self.watch = DriveWatch(drive, settings.silent_drive_s)
        self.link_ok = False
        self.emcy = ""                  # the last EMCY, as text
        self.fault = ""                 # the drive's current fault, as text ("" when none)
        self.history: tuple[str, ...] = ()   # the drive's last errors (0x1003), newest first
        self.target_qc = 0              # the target the drive was last sent
        self.arming: ArmSequence | None = None
        self._checking: Calibration | None = None     # being written to the drive
        self._disable_at: float | None = None
        self._seen_feedback = 0
        self._now = 0.0                                # the time last told, for the throttled log
        self._estops = Throttled(log, "estop", clock=lambda: self._now)
        self._backoff = Backoff(settings.reconnect_min_s, settings.reconnect_max_s)
        self._out: list = []

    @property
    def drive_alive(self) -> bool:
        return self.watch.alive

    # -- life ------------------------------------------------------------------------------
    def start(self, now: float) -> list:
        self._connect()
        return self._take()

    def connected(self, now: float, error: str = "") -> list:
        """The link opened (or not: `error`)."""
        if error:
            self._backoff.failed(now)
        else:
            self.link_ok = True
            self._configure()
        return self._take()

    def configured(self, now: float, error: str = "", link_error: str = "",
                   history: tuple[str, ...] = ()) -> list:
        """Configuration done (with the drive's error history, newest first); or the drive
        refused or did not answer (`error`, retried later); or the link itself went away
        (`link_error`, reconnect now)."""
        if link_error:
            log.warning("drive configuration failed: %s", link_error)
            self._connect()
        elif error:
            log.warning("drive configuration failed: %s", error)
            self._backoff.failed(now)
        else:
            self._backoff.succeeded()
            self.history = tuple(history)
            if history:
                log.info("drive's error history, newest first: %s", "; ".join(history))
            self.watch.configured_at = now
            self.recorder.reset()
            self.phase = Phase.CALIBRATING
            log.info("calibration: power stage off; turn the wheel to both locks and back to the centre")
        return self._take()

    def limits_written(self, now: float, calibration: Calibration, error: str = "") -> list:
        """The drive took the calibrated limits (or refused them: sweep again)."""
        if self.phase is not Phase.CHECKING or calibration is not self._checking:
            log.debug("limits written for a calibration no longer wanted")
            return []
        self._checking = None
        if error:
            log.error("could not write the software position limits: %s; sweep again", error)
            self.recorder.reset()
            self.recorder.problem = f"drive refused the limits: {error}"
            self.phase = Phase.CALIBRATING
        else:
            self.calibration = calibration
            self.envelope.set_range(*calibration.range_deg)
            self.phase = Phase.READY
            lo, hi = calibration.range_deg
            log.info("calibrated: min %d max %d zeroRef %d (span %d qc), range %.1f..%.1f deg",
                     calibration.min_qc, calibration.max_qc, calibration.zero_qc, calibration.span_qc, lo, hi)
        return self._take()

    def link_lost(self, now: float, error: str) -> list:
        if self.link_ok:
            self.link_ok = False
            self.envelope.trip(TripCause.LINK_LOST, f": {error}")
            self._abort_arm(f"CAN link lost: {error}", power_off=False)
            self.watch.alive = False
            log.error("CAN link lost: %s; reconnecting", error)
            self._connect()
        return self._take()

    def shutdown(self, now: float) -> tuple[list, float]:
        """The service is stopping: stop the wheel. Returns the frames and how long to let
        the control loop hold the quick stop before the final `power_off`."""
        was_armed = self.envelope.armed
        self._stop_drive(now, TripCause.SERVICE_STOPPING)
        hold_s = self.settings.quickstop_hold_s if was_armed and self.link_ok else 0.0
        return self._take(), hold_s

    def power_off(self) -> list:
        """The last frame before the link closes."""
        return [Command(ds402.CW_DISABLE_VOLTAGE)] if self.link_ok else []

    # -- the control period ----------------------------------------------------------------
    def tick(self, now: float, reading: DriveReading) -> list:
        """Once per SYNC period: supervision, the sweep, the arm in progress, the envelope's
        watchdog and ramp, a pending power-off, and the period's frames."""
        if self._backoff.due(now):
            self._connect()
        if self.link_ok:
            self._control(now, reading)
        return self._take()

    def _control(self, now: float, reading: DriveReading) -> None:
        fb = reading.feedback
        self._supervise(now, reading)
        fresh = self.fresh(fb, now)
        if self.phase is Phase.CALIBRATING and fresh and fb.count != self._seen_feedback:
            self._sweep_sample(fb, now)
        self._seen_feedback = fb.count
        if self.arming is not None:
            self._arming_step(now, fb)
        target_qc = None
        if self.envelope.armed:
            measured = self.calibration.angle_deg(fb.position_qc) if fresh else None
            target, tripped = self.envelope.tick(measured, now)
            if tripped:
                self._stop_drive(now)
            elif target is not None:
                target_qc = self.target_qc = round(self.calibration.qc_of(target))
        if self._disable_at is not None and now >= self._disable_at:
            self._disable_at = None
            self._emit(Command(ds402.CW_DISABLE_VOLTAGE))
        self._emit(Cycle(target_qc))

    def _supervise(self, now: float, reading: DriveReading) -> None:
        fb = reading.feedback
        changed, reconfigure = self.watch.observe(now, reading, self.phase is Phase.CONNECTING)
        if changed is True:
            log.info("drive heartbeat: ok")
        elif changed is False:
            log.error("drive heartbeat lost")
            self._stop_drive(now, TripCause.DRIVE_HEARTBEAT)
        if reconfigure:
            self._reconfigure(now, reconfigure)
        if self.envelope.armed:
            if not self.fresh(fb, now):
                self._stop_drive(now, TripCause.FEEDBACK_TIMEOUT)
            elif fb.state != ds402.OPERATION_ENABLED:
                self._stop_drive(now, TripCause.NOT_ENABLED, f" ({fb.state})")

    def _sweep_sample(self, fb: Feedback, now: float) -> None:
        r = self.recorder
        problem = r.problem
        r.add(fb.position_qc, now)
        if r.problem != problem and r.problem:
            log.warning("calibration: %s", r.problem)
        if r.done(now):
            try:
                cal = r.result()
            except CalibrationRefused as exc:
                log.warning("calibration refused: %s; sweep again", exc)
                r.reset()
                r.problem = str(exc)
                return
            self._check(cal)

    # -- events from the drive -------------------------------------------------------------
    def on_emcy(self, now: float, emcy: Emcy) -> list:
        self.emcy = str(emcy)
        if emcy.is_reset:
            self.fault = ""
            log.info("drive: all errors cleared")
        else:
            self.fault = str(emcy)
            log.error("drive %s", emcy)
            if emcy.code == LIFE_GUARD_ERROR:          # the text: "drive " + str(emcy), as ever
                self._stop_drive(now, TripCause.LIFE_GUARD, f" {emcy.name}")
            else:
                self._stop_drive(now, TripCause.DRIVE_FAULT, f" 0x{emcy.code:04X} {emcy.name}")
        return self._take()

    def on_bootup(self, now: float) -> list:
        """The drive announced a (re)boot: its configuration and its counter are gone."""
        self._reconfigure(now, TripCause.DRIVE_REBOOTED)
        return self._take()

    # -- requests --------------------------------------------------------------------------
    def handle(self, request: Request, now: float, wall_ns: int, reading: DriveReading,
               token: object = None) -> tuple[dict | None, list]:
        """The answer to a request, and what to do. An arm answers later, as
        `Reply(token, answer)` from a tick, once the drive is enabled (answer None)."""
        fb = reading.feedback
        if isinstance(request, (Setpoint, BadSetpoint)):
            answer = self._setpoint(request, now, wall_ns, fb)
        elif isinstance(request, Arm):
            answer = self._arm(request, now, reading, token)
        elif isinstance(request, Disarm):
            answer = self._disarm(request, now)
        elif isinstance(request, Estop):
            answer = self._estop(now, request.by)
        elif isinstance(request, CalibrationRequest):
            answer = self._calibration_request(request, now)
        elif isinstance(request, Refused):
            answer = _rejected(request.reason)
        else:
            raise TypeError(f"not a request: {request!r}")
        return answer, self._take()

    def _estop(self, now: float, by: str = "") -> dict:
        """Quick stop now, whoever asks and whatever they send; disarms. Logged with the
        sender when it says who it is; a flood of them is a line per cause and interval."""
        was_armed = self.envelope.armed
        self._stop_drive(now, TripCause.ESTOP)
        self._now = now
        sender = f"from '{by}' (as it says)" if by else "from a sender that did not say who"
        self._estops.log(f"{'was armed' if was_armed else 'was not armed'}, {sender}")
        return {"status": ACCEPTED, "reason": "quick stop, then power off", "was_armed": was_armed}

    def _arm(self, request: Arm, now: float, reading: DriveReading, token) -> dict | None:
        fb, lease = reading.feedback, request.lease
        if self.phase not in (Phase.READY, Phase.ARMED):
            return _rejected(f"not ready: {self.phase.value}")
        if not self.drive_alive:
            return _rejected("the drive is not answering (no heartbeat)")
        if not self.fresh(fb, now):
            return _rejected("no feedback from the drive")
        if self.arming is not None:
            return _rejected("another client is arming")
        angle = self.calibration.angle_deg(fb.position_qc)
        refusal = self.envelope.arm_refusal(angle, lease)
        if refusal:
            return _rejected(refusal)
        if self.envelope.armed:               # the owner arming again: a renewal
            self.envelope.arm(angle, now, lease)
            return self._arm_reply(lease, fb)
        if fb.op_mode != POSITION_MODE:
            return _rejected(f"drive is in operation mode {fb.op_mode}, not Position Mode")
        self._disable_at = None               # a power-off pending from the last stop is ours now
        self.arming, frames = ArmSequence.begin(token, fb, now, self.settings.arm_step_timeout_s, self.fault)
        self._emit_frames(frames)
        return None

    def _arming_step(self, now: float, fb: Feedback) -> None:
        seq = self.arming
        self._emit_frames(seq.advance(fb, now, self.fault))
        if seq.failure:
            self._abort_arm(seq.failure)
        elif seq.done:                       # enabled, holding the wheel at target_qc
            angle = self.calibration.angle_deg(self.target_qc) if self.calibration else None
            refusal = self.envelope.arm_refusal(angle) if angle is not None else "not calibrated"
            if refusal:
                self._abort_arm(refusal)
                return
            self.arming = None
            lease = self.envelope.arm(angle, now)
            self.phase = Phase.ARMED
            self.fault = ""
            self._emit(Reply(seq.token, self._arm_reply(lease, fb)))

    def _abort_arm(self, reason: str, power_off: bool = True) -> None:
        """An arm in progress fails: tell whoever asked; power off at once unless the
        caller stops the drive its own way."""
        seq, self.arming = self.arming, None
        if seq is None:
            return
        if power_off and self.link_ok:
            self._emit(Command(ds402.CW_DISABLE_VOLTAGE))
        self._emit(Reply(seq.token, _rejected(reason)))

    def _arm_reply(self, lease: str, fb: Feedback) -> dict:
        lo, hi = self.envelope.allowed_deg
        env = self.envelope
        return {"status": ACCEPTED, "reason": "", "lease": lease, "owner": env.owner,
                "angle_deg": self.calibration.measured_deg(fb.position_qc),
                "target_deg": env.target_deg, "range_deg": [lo, hi],
                "watchdog_s": env.settings.watchdog_s,
                # what a client plans inside (services/pilot): the speed envelope's figures
                "envelope": {**env.lateral.as_dict(), "slew_deg_s": env.settings.slew_deg_s}}

    def _disarm(self, request: Disarm, now: float) -> dict:
        if not self.envelope.armed:
            return {"status": ACCEPTED, "reason": "was not armed"}
        if not self.envelope.disarm(request.lease):
            return _rejected("only the owner can disarm (anyone can estop)")
        self._stop_drive(now)
        self.phase = Phase.READY
        return {"status": ACCEPTED, "reason": "disarmed: quick stop, then power off"}

    def _setpoint(self, request: Setpoint | BadSetpoint, now: float, wall_ns: int, fb: Feedback) -> dict:
        cal = self.calibration
        measured = cal.angle_deg(fb.position_qc) if cal is not None and self.fresh(fb, now) else None
        was_armed = self.envelope.armed
        d = self.envelope.setpoint(request, measured, now, wall_ns)
        if was_armed and not self.envelope.armed:          # it came after the deadline
            self._stop_drive(now)
        if d.target_deg is not None:
            self.target_qc = round(cal.qc_of(d.target_deg))
            self._emit(SendTarget(self.target_qc))
        reply = {"status": d.status, "reason": d.reason, "target_deg": d.target_deg,
                 "angle_deg": None if measured is None else cal.measured_deg(fb.position_qc),
                 "limits": list(d.limits)}
        if d.speed_mps is not None:
            reply["speed_mps"], reply["speed_source"] = d.speed_mps, d.speed_source
        if d.goal_deg is not None and d.goal_deg != d.target_deg:
            reply["goal_deg"] = d.goal_deg
        return reply

    def _calibration_request(self, request: CalibrationRequest, now: float) -> dict:
        if request.action == "restart":
            if self.envelope.armed:
                return _rejected("disarm first")
            if self.phase is Phase.CONNECTING:
                return _rejected("the drive is not configured yet")
            self._abort_arm("calibration restarted", power_off=False)     # powered off below
            self.recorder.reset()
            self._forget_calibration()
            self.phase = Phase.CALIBRATING
            self._emit(Command(ds402.CW_DISABLE_VOLTAGE))
            log.info("calibration restarted: turn the wheel to both locks and back to the centre")
        elif request.action == "finish":
            if self.phase is not Phase.CALIBRATING:
                return _rejected(f"no sweep in progress ({self.phase.value})")
            try:
                cal = self.recorder.result()
            except CalibrationRefused as exc:
                log.warning("calibration refused: %s", exc)
                self.recorder.problem = str(exc)
                return {"status": REJECTED, "reason": f"calibration refused: {exc}",
                        "calibration": self.calibration_state()}
            self._check(cal)
        return {"status": ACCEPTED, "reason": "", "calibration": self.calibration_state()}

    # -- shared steps ----------------------------------------------------------------------
    def fresh(self, fb: Feedback, now: float) -> bool:
        """Whether the drive's last TPDO is recent enough to act on."""
        return now - fb.received_s <= self.settings.feedback_timeout_s

    def _stop_drive(self, now: float, cause: TripCause | None = None, detail: str = "") -> None:
        """Quick stop now, power off later; `cause` (and its `detail`) trips the envelope (none
        for a disarm, or when the envelope tripped itself)."""
        if cause is not None:
            self.envelope.trip(cause, detail)
        if self.arming is not None:           # the stop's own quick stop and power-off follow
            self._abort_arm(f"stopped while arming ({self.envelope.tripped or 'estop'})", power_off=False)
        if self.phase is Phase.ARMED:
            self.phase = Phase.READY
        if self.link_ok:
            self._emit(Command(ds402.CW_QUICK_STOP))
            self._disable_at = now + self.settings.quickstop_hold_s

    def _check(self, cal: Calibration) -> None:
        """A sweep gave `cal`: write its limits to the drive before trusting it."""
        self.phase = Phase.CHECKING
        self._checking = cal
        self._emit(WriteLimits(cal))

    def _forget_calibration(self) -> None:
        self.calibration = self._checking = None
        self.envelope.clear_range()

    def _reconfigure(self, now: float, cause: TripCause) -> None:
        self._stop_drive(now, cause)
        self._configure()

    def _connect(self) -> None:
        self.link_ok = False
        self.phase = Phase.CONNECTING
        self._backoff.cancel()
        self._emit(Connect())

    def _configure(self) -> None:
        self.phase = Phase.CONNECTING
        self._backoff.cancel()
        self._forget_calibration()
        self._emit(Configure())

    def _emit(self, action) -> None:
        self._out.append(action)

    def _emit_frames(self, frames: list) -> None:
        for frame in frames:
            if isinstance(frame, SendTarget):
                self.target_qc = frame.target_qc
            self._emit(frame)

    def _take(self) -> list:
        out, self._out = self._out, []
        return out

    def fault_text(self, fb: Feedback, now: float) -> str:
        """The drive's active fault: its EMCY, or that it reports one without an EMCY."""
        if self.fault:
            return self.fault
        if not (self.fresh(fb, now) and ds402.is_fault(fb.statusword)):
            return ""
        if self.history:
            return f"drive in fault: {self.history[0]} (its error history; no EMCY seen)"
        return "drive in fault (no EMCY seen)"

    def calibration_state(self) -> dict:
        """The `calibration` field of the state and of calibration replies."""
        if self.calibration is not None:
            return {"state": "done", **self.calibration.as_dict(), "problem": ""}
        state = {Phase.CALIBRATING: "sweeping", Phase.CHECKING: "checking"}.get(self.phase, "none")
        return {"state": state, **self.recorder.status()}


def _rejected(reason: str) -> dict:
    return {"status": REJECTED, "reason": reason}
