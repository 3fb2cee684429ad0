"""Acquisition times for a device that samples on a steady cadence but whose bytes reach
the host in bursts (USB latency timer, scheduling: the car's logs show 6-7 frames arriving
together every 81 ms).

A frame cannot arrive before it was acquired, and frame k was acquired about k periods
after frame 0, so `arrival_k - k * period` is never below the true start offset and
touches it whenever a frame happens to get through quickly. The clock keeps the minimum
of that over a sliding window (a couple of seconds, so a device clock a little off its
nominal rate is followed) and stamps frame k at `k * period + minimum`.
"""
from __future__ import annotations

from collections import deque


class CadenceClock:
    def __init__(self, period_s: float, window_s: float = 2.0, restart_after_s: float = 0.25):
        self.period_ns = int(period_s * 1e9)
        self.window = max(2, int(window_s / period_s))
        self.restart_ns = int(restart_after_s * 1e9)
        self.reset()

    def reset(self) -> None:
        self._base: int | None = None     # arrival of the first frame
        self._slot = 0
        self._last = 0
        self._mins: deque[tuple[int, int]] = deque()   # (slot, arrival - slot * period), increasing

    def stamp(self, arrival_ns: int, slots: int = 1) -> int:
        """Acquisition time of a frame that arrived at `arrival_ns`, `slots` frame periods
        after the previous one (more than 1 when frames were lost in between)."""
        if self._base is not None:
            self._slot += max(1, slots)
            expected = self._base + self._slot * self.period_ns + self._mins[0][1]
            if abs(arrival_ns - expected) > self.restart_ns:
                self.reset()           # silence or a jump no latency explains: start over
        if self._base is None:
            self._base, self._slot = arrival_ns, 0
        x = arrival_ns - self._base - self._slot * self.period_ns
        mins = self._mins
        while mins and mins[-1][1] >= x:
            mins.pop()
        mins.append((self._slot, x))
        while mins[0][0] <= self._slot - self.window:
            mins.popleft()
        t = self._base + self._slot * self.period_ns + mins[0][1]
        t = max(t, self._last + 1)
        self._last = t
        return t
