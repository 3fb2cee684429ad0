"""When the NTRIP client may try the caster again: casters ban clients that retry fast.

The rules (issue 28):

- never two connection attempts less than ``min_interval_s`` (10 s) apart, measured start
  to start, whatever ended the last one (refused, 401, 404, HTML, dropped at once, no data);
- after consecutive failures wait longer: 10, 10, 20, 40 ... s after the failed attempt
  ended, never more than ``max_interval_s`` (60 s);
- after a connection that streamed data for longer than ``min_interval_s``, the next
  attempt may come at once (the caster restarted, or dropped a client it served well);
  a shorter stream is a failure like any other.

Pure: it reads no clock. The client tells it when an attempt started and ended, and asks
when the next may start (all times on one monotonic scale, in seconds).
"""
from __future__ import annotations

from dataclasses import dataclass

#: what casters tolerate (BKG's NtripCaster, RTK2go, SNIP ban clients that reconnect faster)
MIN_INTERVAL_S = 10.0
MAX_INTERVAL_S = 60.0
#: how far short of the allowed time an attempt may start: a clock that wakes at a whole
#: nanosecond (the lockstep clock; monotonic() is ns / 1e9) can fall a rounding short of it
TOLERANCE_S = 1e-6


@dataclass
class RetryPolicy:
    """The backoff between connection attempts. See the module docstring."""

    min_interval_s: float = MIN_INTERVAL_S
    max_interval_s: float = MAX_INTERVAL_S
    #: failed attempts since the last good stream
    failures: int = 0
    _last_start: float | None = None
    _last_end: float | None = None

    def __post_init__(self) -> None:
        if not self.min_interval_s > 0:
            raise ValueError("min_interval_s must be positive")
        self.max_interval_s = max(self.max_interval_s, self.min_interval_s)

    def delay_after_failures(self, failures: int) -> float:
        """The wait after the end of the `failures`-th failure in a row (0 after none)."""
        if failures <= 0:
            return 0.0
        return min(self.min_interval_s * 2.0 ** max(failures - 2, 0), self.max_interval_s)

    def next_start(self) -> float | None:
        """The earliest time the next attempt may start; None before the first attempt."""
        if self._last_start is None:
            return None
        earliest = self._last_start + self.min_interval_s
        if self._last_end is None:               # still under way: at least the 10 s
            return earliest
        return max(earliest, self._last_end + self.delay_after_failures(self.failures))

    def wait_s(self, now: float) -> float:
        """How long to wait from `now` before the next attempt (0: go, also when it is
        less than TOLERANCE_S away)."""
        at = self.next_start()
        if at is None or at - now <= TOLERANCE_S:
            return 0.0
        return at - now

    def started(self, now: float) -> None:
        """An attempt starts now. Refuses one that breaks the minimum interval (by more
        than TOLERANCE_S): a bug in the caller must not get the car's login banned."""
        at = self.next_start()
        if at is not None and now < at - TOLERANCE_S:
            raise RuntimeError(f"connection attempt {at - now:.3f} s too early")
        self._last_start, self._last_end = now, None

    def ended(self, now: float, streamed_s: float = 0.0) -> None:
        """The attempt ended now, after streaming data for `streamed_s` (0: it never did)."""
        self._last_end = now
        if streamed_s > self.min_interval_s:
            self.failures = 0
        else:
            self.failures += 1
