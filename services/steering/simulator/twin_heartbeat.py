"""The heartbeat the EPOS twin consumes (0x1016:1): the host's. Its loss is the CAN life
guard error (0x8130); monitoring starts with the first heartbeat heard."""
from __future__ import annotations


class HostHeartbeat:
    """The host's heartbeat as the drive watches it."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.producer, self.timeout_ms = 0, 0     # from 0x1016:1
        self.last: float | None = None
        #: when the first heartbeat of this host was heard (None: not yet, or lost since)
        self.seen_s: float | None = None

    def configure(self, value: int) -> int | None:
        """0x1016:1 written: a host (re)starting. The COB-ID to hear it on, or None (off)."""
        self.producer, self.timeout_ms = (value >> 16) & 0x7F, value & 0xFFFF
        self.last = self.seen_s = None
        return 0x700 + self.producer if self.producer and self.timeout_ms else None

    def heard(self, now: float) -> None:
        self.last = now
        if self.seen_s is None:
            self.seen_s = now

    def lost(self, now: float) -> bool:
        if not self.timeout_ms or self.last is None:
            return False                             # monitoring starts with the first one
        return now - self.last > self.timeout_ms / 1000.0
