"""What the steering core knows and the steps all its paths share: stop the drive, forget a
calibration, (re)connect and configure, and queue the actions for the runner.

`model/core.py` is the core's life and control period, `model/core_requests.py` what clients
ask of it; both build on this (`SteeringCore` -> `RequestHandling` -> `CoreSteps`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum

from viena.common.log import Throttled
from viena.common.settings import setting
from viena.services.steering.model import ds402
from viena.services.steering.model.actions import (
    Command,
    Configure,
    Connect,
    Reply,
    SendTarget,
    WriteLimits,
)
from viena.services.steering.model.arming import ArmSequence
from viena.services.steering.model.calibration import (
    Calibration,
    CalibrationSettings,
    SweepRecorder,
)
from viena.services.steering.model.drive import DriveSettings, Feedback
from viena.services.steering.model.safety import REJECTED, Envelope
from viena.services.steering.model.supervision import Backoff, DriveWatch
from viena.services.steering.model.trips import TripCause

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


class CoreSteps:
    """The core's state and the steps shared by its events and requests."""

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

    @property
    def calibrated(self) -> Calibration:
        """The calibration, where only a calibrated core can be (armed or arming)."""
        if self.calibration is None:
            raise RuntimeError("the steering is not calibrated")
        return self.calibration

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

    def _abort_arm(self, reason: str, power_off: bool = True) -> None:
        """An arm in progress fails: tell whoever asked; power off at once unless the
        caller stops the drive its own way."""
        seq, self.arming = self.arming, None
        if seq is None:
            return
        if power_off and self.link_ok:
            self._emit(Command(ds402.CW_DISABLE_VOLTAGE))
        self._emit(Reply(seq.token, rejected(reason)))

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


def rejected(reason: str) -> dict:
    return {"status": REJECTED, "reason": reason}
