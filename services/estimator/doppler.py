"""What the receivers' Doppler speeds say of the car's motion, before any of them is used.

A zero-velocity detector built on the IMU alone cannot tell a car standing from one
cruising down a smooth straight: both read gravity and no turn. GNSS can, and its Doppler
speed is good to centimetres a second from the first fix. So every receiver's speed is
kept here as it comes, admitted or on probation (admission.py: the position needs 10 s
of good fixes before it is used; a Doppler speed of 4 m/s is 4 m/s at once), and the
standstill test and the alignment ask for the slowest and the fastest of the receivers
heard within the last `RECENT_S`: all of them fast, the car moves; all of them slow, it
may stand. A receiver that disagrees with the others outvotes nobody.
"""
from __future__ import annotations

import math

#: a receiver's speed counts this long after its fix (s)
RECENT_S = 1.0


class DopplerSpeeds:
    def __init__(self, max_sigma_mps: float):
        """`max_sigma_mps`: speeds whose horizontal sigma is above this say nothing (the
        admission's `admit_max_speed_sigma_mps`)."""
        self.max_sigma2 = max_sigma_mps * max_sigma_mps
        self.last: dict[str, tuple[int, float]] = {}      # unit -> (t, speed m/s)

    def add(self, fix) -> None:
        """A usable fix, whether or not its receiver is in use."""
        if not fix.has_velocity:
            return
        s = fix.vel_sigma_mps
        if s is not None and s[0] * s[0] + s[1] * s[1] > self.max_sigma2:
            return
        v = fix.vel_ecef_mps
        t = self.last.get(fix.unit, (fix.t,))[0]
        if fix.t >= t:
            self.last[fix.unit] = (fix.t, math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))

    def span(self, t: int) -> tuple[float, float] | None:
        """(slowest, fastest) speed of the receivers heard within RECENT_S of `t`, or None."""
        lo, hi = math.inf, -1.0
        for tf, speed in self.last.values():
            if -RECENT_S * 1e9 < t - tf < RECENT_S * 1e9:
                lo, hi = min(lo, speed), max(hi, speed)
        return None if hi < 0.0 else (lo, hi)

    def forget(self) -> None:
        """A new timeline: the speeds' times mean nothing."""
        self.last.clear()
