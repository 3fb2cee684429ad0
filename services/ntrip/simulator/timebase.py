"""The caster twin's GPS time: true GPS time by default, or a faster one for tests.

A base stamps its epochs on whole GPS seconds, so the caster and the receiver twins must
agree on GPS time: it is anchored once to the host's UTC (viena.common.clock, converted
with the leap seconds of services/gnss/driver/gpstime.py, as the receiver twin's GpsClock
does) and then runs on the monotonic clock. `rate` > 1 runs it faster than real time, so
a test sees 20 epochs in a second; every `_s` setting of the caster is on this clock.
"""
from __future__ import annotations

from viena.common import clock
from viena.services.gnss.driver.gpstime import utc_to_gps_ns


class Timebase:
    """GPS seconds (since 1980-01-06) now, running `rate` times as fast as real time."""

    def __init__(self, rate: float = 1.0, start_gps_s: float | None = None):
        if not rate > 0:
            raise ValueError(f"a timebase's rate is positive, not {rate}")
        self.rate = float(rate)
        self._start_gps_s = start_gps_s
        self._anchor: tuple[float, float] | None = None     # (monotonic s, GPS s)

    def now(self) -> float:
        """GPS seconds now."""
        mono = clock.monotonic()
        if self._anchor is None:
            start = self._start_gps_s
            if start is None:
                start = utc_to_gps_ns(clock.time_ns()) / 1e9
            self._anchor = (mono, float(start))
        m0, g0 = self._anchor
        return g0 + (mono - m0) * self.rate

    def real_s(self, seconds: float) -> float:
        """How long `seconds` of this clock last in real time."""
        return max(0.0, seconds) / self.rate
