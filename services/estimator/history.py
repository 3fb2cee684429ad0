"""The last second of the estimated trajectory, so that a late GNSS fix meets the state of
its own time rather than the state of its arrival."""
from __future__ import annotations

from collections import deque

from viena.common.rotation import wrap_angle


class TrajectoryHistory:
    """The recent IMU-rate trajectory, so that a late fix meets the state of its own time.

    Entries hold the state minus the corrections applied so far; adding the corrections
    of now gives the state as we now believe it was then.
    """

    def __init__(self, window_ns: int):
        self.window_ns = window_ns
        self.entries: deque = deque()
        self.corr = [0.0] * 7          # p(3), v(3), yaw

    def clear(self) -> None:
        self.entries.clear()

    def append(self, t, x, yaw) -> None:
        """The state at t: x = [p(3), v(3), ...] and the yaw."""
        c = self.corr
        self.entries.append((t, x[0] - c[0], x[1] - c[1], x[2] - c[2],
                             x[3] - c[3], x[4] - c[4], x[5] - c[5], yaw - c[6]))
        oldest = t - self.window_ns
        entries = self.entries
        while entries[0][0] < oldest:
            entries.popleft()

    def correct(self, dp=None, dv=None, dyaw=0.0) -> None:
        c = self.corr
        if dp is not None:
            c[0:3] = [c[0] + dp[0], c[1] + dp[1], c[2] + dp[2]]
        if dv is not None:
            c[3:6] = [c[3] + dv[0], c[4] + dv[1], c[5] + dv[2]]
        c[6] += dyaw

    def raw_position(self, t: int, x_now, t_now: int | None):
        """The position at t on the trajectory as the IMU moved it, every position
        correction left out (so that differences of it are the IMU's own displacements),
        or None if t is not covered. `x_now`, `t_now`: the state now."""
        if t_now is None or t >= t_now:
            c = self.corr
            return [x_now[0] - c[0], x_now[1] - c[1], x_now[2] - c[2]]
        then = self._interpolate(t)
        return None if then is None else then[0:3]

    def at(self, t: int):
        """(p, v, yaw) at time t, interpolated, or None if t is not covered."""
        vals = self._interpolate(t)
        if vals is None:
            return None
        c = self.corr
        return ([vals[k] + c[k] for k in range(3)],
                [vals[3 + k] + c[3 + k] for k in range(3)],
                wrap_angle(vals[6] + c[6]))

    def _interpolate(self, t: int):
        """The stored entry values at t (corrections not added), or None."""
        entries = self.entries
        if not entries or t < entries[0][0]:
            return None
        i = len(entries) - 1
        while i > 0 and entries[i][0] > t:
            i -= 1
        a = entries[i]
        if t > a[0] and i + 1 < len(entries):
            b = entries[i + 1]
            f = (t - a[0]) / (b[0] - a[0])
            vals = [a[k] + f * (b[k] - a[k]) for k in range(1, 7)]
            vals.append(a[7] + f * wrap_angle(b[7] - a[7]))
        else:
            vals = list(a[1:])
        return vals
