"""What clients ask of the steering core: arm (and its DS402 sequence), disarm, setpoints,
e-stops and the calibration's restart or finish. Each answers at once, except an arm, which
answers from a later tick once the drive is enabled."""
from __future__ import annotations

import logging

from viena.services.steering.model import ds402
from viena.services.steering.model.actions import (
    Command,
    DriveReading,
    Reply,
    SendTarget,
)
from viena.services.steering.model.arming import ArmSequence
from viena.services.steering.model.calibration import (
    CalibrationRefused,
)
from viena.services.steering.model.core_steps import CoreSteps, Phase, rejected
from viena.services.steering.model.drive import POSITION_MODE, Feedback
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
from viena.services.steering.model.safety import ACCEPTED, REJECTED
from viena.services.steering.model.trips import TripCause

log = logging.getLogger("viena.steering")


class RequestHandling(CoreSteps):
    """The core's answers to requests (model/requests.py)."""

    def handle(self, request: Request, now: float, wall_ns: int, reading: DriveReading,
               token: object = None) -> tuple[dict | None, list]:
        """The answer to a request, and what to do. An arm answers later, as
        `Reply(token, answer)` from a tick, once the drive is enabled (answer None)."""
        fb = reading.feedback
        answer: dict | None
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
            answer = rejected(request.reason)
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
            return rejected(f"not ready: {self.phase.value}")
        if not self.drive_alive:
            return rejected("the drive is not answering (no heartbeat)")
        if not self.fresh(fb, now):
            return rejected("no feedback from the drive")
        if self.arming is not None:
            return rejected("another client is arming")
        angle = self.calibrated.angle_deg(fb.position_qc)          # ready: calibrated
        refusal = self.envelope.arm_refusal(angle, lease)
        if refusal:
            return rejected(refusal)
        if self.envelope.armed:               # the owner arming again: a renewal
            return self._arm_reply(self.envelope.arm(angle, now, lease), fb)
        if fb.op_mode != POSITION_MODE:
            return rejected(f"drive is in operation mode {fb.op_mode}, not Position Mode")
        self._disable_at = None               # a power-off pending from the last stop is ours now
        self.arming, frames = ArmSequence.begin(token, fb, now, self.settings.arm_step_timeout_s, self.fault)
        self._emit_frames(frames)
        return None

    def _arming_step(self, now: float, fb: Feedback) -> None:
        seq = self.arming
        if seq is None:
            return
        self._emit_frames(seq.advance(fb, now, self.fault))
        if seq.failure:
            self._abort_arm(seq.failure)
        elif seq.done:                       # enabled, holding the wheel at target_qc
            angle = self.calibration.angle_deg(self.target_qc) if self.calibration else None
            refusal = self.envelope.arm_refusal(angle) if angle is not None else "not calibrated"
            if refusal or angle is None:
                self._abort_arm(refusal or "not calibrated")
                return
            self.arming = None
            lease = self.envelope.arm(angle, now)
            self.phase = Phase.ARMED
            self.fault = ""
            self._emit(Reply(seq.token, self._arm_reply(lease, fb)))

    def _arm_reply(self, lease: str, fb: Feedback) -> dict:
        lo, hi = self.envelope.calibrated_allowed_deg
        env = self.envelope
        return {"status": ACCEPTED, "reason": "", "lease": lease, "owner": env.owner,
                "angle_deg": self.calibrated.measured_deg(fb.position_qc),
                "target_deg": env.target_deg, "range_deg": [lo, hi],
                "watchdog_s": env.settings.watchdog_s,
                # what a client plans inside (services/pilot): the speed envelope's figures
                "envelope": {**env.lateral.as_dict(), "slew_deg_s": env.settings.slew_deg_s}}

    def _disarm(self, request: Disarm, now: float) -> dict:
        if not self.envelope.armed:
            return {"status": ACCEPTED, "reason": "was not armed"}
        if not self.envelope.disarm(request.lease):
            return rejected("only the owner can disarm (anyone can estop)")
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
            self.target_qc = round(self.calibrated.qc_of(d.target_deg))
            self._emit(SendTarget(self.target_qc))
        reply = {"status": d.status, "reason": d.reason, "target_deg": d.target_deg,
                 "angle_deg": None if measured is None or cal is None else cal.measured_deg(fb.position_qc),
                 "limits": list(d.limits)}
        if d.speed_mps is not None:
            reply["speed_mps"], reply["speed_source"] = d.speed_mps, d.speed_source
        if d.goal_deg is not None and d.goal_deg != d.target_deg:
            reply["goal_deg"] = d.goal_deg
        return reply

    def _calibration_request(self, request: CalibrationRequest, now: float) -> dict:
        if request.action == "restart":
            if self.envelope.armed:
                return rejected("disarm first")
            if self.phase is Phase.CONNECTING:
                return rejected("the drive is not configured yet")
            self._abort_arm("calibration restarted", power_off=False)     # powered off below
            self.recorder.reset()
            self._forget_calibration()
            self.phase = Phase.CALIBRATING
            self._emit(Command(ds402.CW_DISABLE_VOLTAGE))
            log.info("calibration restarted: turn the wheel to both locks and back to the centre")
        elif request.action == "finish":
            if self.phase is not Phase.CALIBRATING:
                return rejected(f"no sweep in progress ({self.phase.value})")
            try:
                cal = self.recorder.result()
            except CalibrationRefused as exc:
                log.warning("calibration refused: %s", exc)
                self.recorder.problem = str(exc)
                return {"status": REJECTED, "reason": f"calibration refused: {exc}",
                        "calibration": self.calibration_state()}
            self._check(cal)
        return {"status": ACCEPTED, "reason": "", "calibration": self.calibration_state()}

