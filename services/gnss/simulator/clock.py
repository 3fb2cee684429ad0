"""A simulated receiver's GPS clock, on the monotonic time its twin is polled with."""
from __future__ import annotations

import math

from viena.common import clock
from viena.services.gnss.driver.gpstime import NS_PER_MS, SECONDS_PER_WEEK, utc_to_gps_ns

WEEK_MS = SECONDS_PER_WEEK * 1000


class GpsClock:
    """GPS milliseconds <-> the twin's monotonic seconds.

    Anchored at first use to the host's clock: GPS time is true time, and the host's
    clock is the truest one a simulation has (the car's truth follows it too).
    """

    def __init__(self) -> None:
        self.offset_ms: float | None = None     # GPS ms = now_s * 1000 + offset_ms

    def anchor(self, now_s: float, gps_ms: float | None = None) -> None:
        if gps_ms is None:
            gps_ms = utc_to_gps_ns(clock.time_ns()) / NS_PER_MS
        self.offset_ms = gps_ms - now_s * 1000.0

    def ensure(self, now_s: float) -> None:
        if self.offset_ms is None:
            self.anchor(now_s)

    def gps_ms(self, now_s: float) -> int:
        """GPS time at ``now_s``, ms since the GPS epoch (rounded down)."""
        assert self.offset_ms is not None, "anchored first (anchor or ensure)"
        return int(math.floor(now_s * 1000.0 + self.offset_ms))

    def now_of(self, gps_ms: float) -> float:
        assert self.offset_ms is not None, "anchored first (anchor or ensure)"
        return (gps_ms - self.offset_ms) / 1000.0
