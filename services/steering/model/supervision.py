"""Keeping the drive in reach: is it there, can its configuration be trusted, and when to try
the link again. Plain data, told the time; `core.SteeringCore` decides what to do about it.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

from viena.services.steering.model.actions import DriveReading
from viena.services.steering.model.drive import NMT_OPERATIONAL, DriveSettings
from viena.services.steering.model.trips import TripCause

log = logging.getLogger("viena.steering")


@dataclass
class DriveWatch:
    """The drive's heartbeat: alive or lost, and whether to configure it again because it went
    silent for `silent_drive_s` (powered off, or rebooted with its boot-up message lost) or
    announces a state other than operational (an NMT command from another host)."""
    drive: DriveSettings
    silent_drive_s: float
    alive: bool = False
    configured_at: float = float("-inf")
    not_operational_since: float | None = None

    def observe(self, now: float, reading: DriveReading, configuring: bool) -> tuple[bool | None, TripCause | None]:
        """(True or False when `alive` just changed, else None; why to configure the drive
        again, or None). `configuring`: a configuration is under way, nothing to redo."""
        age = reading.heartbeat_age_s
        alive = age <= self.drive.drive_heartbeat_timeout_s
        changed = alive if alive != self.alive else None
        self.alive = alive
        silent = min(age, now - self.configured_at)
        if not alive and not configuring and silent > self.silent_drive_s:
            log.error("drive silent for %.1f s: configuring it again when it answers", silent)
            self.not_operational_since = None
            return changed, TripCause.DRIVE_SILENT
        return changed, self._not_operational(now, reading.nmt_state, configuring)

    def _not_operational(self, now: float, state: int | None, configuring: bool) -> TripCause | None:
        if not self.alive or configuring or state in (None, NMT_OPERATIONAL):
            self.not_operational_since = None
            return None
        if self.not_operational_since is None:
            self.not_operational_since = now
        elif now - self.not_operational_since > 3 * self.drive.drive_heartbeat_period_s:
            log.warning("drive reports NMT state %d, not operational: configuring it again", state)
            self.not_operational_since = None
            return TripCause.NOT_OPERATIONAL
        return None


@dataclass
class Backoff:
    """When to open the link again after a failure: `min_s`, doubling up to `max_s`."""
    min_s: float
    max_s: float
    retry_at: float | None = None

    def __post_init__(self):
        self.delay_s = self.min_s

    def failed(self, now: float) -> None:
        self.retry_at = now + self.delay_s
        self.delay_s = min(self.delay_s * 2, self.max_s)

    def due(self, now: float) -> bool:
        return self.retry_at is not None and now >= self.retry_at

    def cancel(self) -> None:
        self.retry_at = None

    def succeeded(self) -> None:
        self.retry_at, self.delay_s = None, self.min_s
