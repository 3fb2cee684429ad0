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

This module is the core's life and control period; what clients ask is in
`model/core_requests.py`, the state and the shared steps in `model/core_steps.py`.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from viena.services.steering.model import ds402
from viena.services.steering.model.actions import (
    Command,
    Cycle,
    DriveReading,
)
from viena.services.steering.model.calibration import (
    Calibration,
    CalibrationRefused,
)
from viena.services.steering.model.core_requests import RequestHandling
from viena.services.steering.model.core_steps import ControllerSettings, Phase
from viena.services.steering.model.drive import Feedback
from viena.services.steering.model.trips import TripCause

if TYPE_CHECKING:                     # the driver's package loads the CAN stack
    from viena.services.steering.driver.emcy import Emcy

#: the EMCY the drive sends when the host's heartbeat stops (driver/emcy.py LIFE_GUARD_ERROR)
LIFE_GUARD_ERROR = 0x8130

log = logging.getLogger("viena.steering")

__all__ = ["ControllerSettings", "Phase", "SteeringCore"]


class SteeringCore(RequestHandling):
    """The phase machine, the drive's supervision and the stops around the envelope."""

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
            measured = self.calibrated.angle_deg(fb.position_qc) if fresh else None
            target, tripped = self.envelope.tick(measured, now)
            if tripped:
                self._stop_drive(now)
            elif target is not None:
                target_qc = self.target_qc = round(self.calibrated.qc_of(target))
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
