"""What the GNSS fixes say about the IMU's clock.

If the IMU's stamps are late by d (a USB adapter's latency timer, a busy Pi, a firmware
buffer), every IMU sample is fused as if the car had done then what it did d earlier.
The Kalman filter hides most of it (each fix pulls position and velocity back), so the
residuals themselves say little; the raw signals say it plainly: the course over ground
turns when the car turns, and the gyro saw that turn d later (by its stamps). So, as
`viena calibrate imu time` does offline (services/imu/model/time_offset.py), the course
changes between fixes are compared with the gyro's yaw change over the same interval
shifted by each candidate lag, and the lag where they agree best (least squares,
forgetting over `TAU_S`) is the offset they point at; how much better it fits than no
lag at all says how sure that is.

The estimator reports it (the state's `imu_time_offset_hint_s`, in the IMU service's
convention: the `time_offset_s` to set, t_true = t_stamped + offset) and, until it is set,
counts it as uncertainty: each fix is widened by what the offset makes of it
(docs/estimator.md#imu-time-offsets), so that a wrong clock costs accuracy, not the
estimate.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

#: candidate lags: the IMU's stamps later than the truth by this much (s)
LAGS_S = np.round(np.arange(-0.8, 0.8001, 0.02), 3)
#: the fit forgets over this long (s)
TAU_S = 60.0
#: courses are compared above this speed (m/s) ...
MIN_SPEED_MPS = 2.0
#: ... between fixes about this far apart (s), at most this far
PAIR_S, MAX_GAP_S = 1.0, 1.6
#: a lag is reported once it fits this much better than none (a chi-square difference) ...
SIGNIFICANT_CHI2 = 25.0
#: ... and is at least this large (s)
SIGNIFICANT_S = 0.03
#: the gyro's yaw kept, s (the largest lag and fix gap, and then some), on a grid of
_KEEP_S = 3.5
_GRID_NS = 20_000_000
#: the index of the lag 0
_ZERO_LAG = int(np.argmin(np.abs(LAGS_S)))


class OffsetHint:
    def __init__(self) -> None:
        self._stamps: deque = deque()       # stamps (ns) on a GRID_NS grid ...
        self._yaws: deque = deque()         # ... and the yaw integrated from the gyro then, rad
        self._yaw = 0.0
        self._courses: deque = deque()      # (t ns, course rad, variance) of recent fixes
        self._waiting: deque = deque()      # (t0, t1, course turned, variance) to compare
        self._sse = np.zeros(len(LAGS_S))   # weighted squared misfit per lag
        self._t: int | None = None
        self._late: float | None = None     # late_s as of the last _compare (read every state)

    def gyro(self, t: int, yaw_rate: float, dt: float) -> None:
        """One IMU sample: the yaw rate (rad/s, bias-corrected) over the dt before stamp t."""
        self._yaw += yaw_rate * dt
        stamps = self._stamps
        if stamps and t - stamps[-1] < _GRID_NS:
            return
        stamps.append(t)
        self._yaws.append(self._yaw)
        while stamps[0] < t - _KEEP_S * 1e9:
            stamps.popleft()
            self._yaws.popleft()
        # a pair of courses is compared once the gyro has passed its latest lag
        waiting = self._waiting
        while waiting and waiting[0][1] + LAGS_S[-1] * 1e9 <= t:
            self._compare(*waiting.popleft())

    def course(self, t: int, ve: float, vn: float, var_v: float) -> None:
        """A fix's horizontal velocity of the body origin (ENU m/s, its variance per axis)
        at true time t."""
        speed2 = ve * ve + vn * vn
        if speed2 < MIN_SPEED_MPS ** 2:
            self._courses.clear()
            return
        course, var = math.atan2(-ve, vn), var_v / speed2
        courses = self._courses
        while courses and t - courses[0][0] > MAX_GAP_S * 1e9:
            courses.popleft()
        # the turn over about a second: long enough that a lag shows through the noise
        while courses and t - courses[0][0] >= PAIR_S * 1e9:
            t0, c0, v0 = courses.popleft()
            self._waiting.append((t0, t, math.remainder(course - c0, math.tau), var + v0))
        courses.append((t, course, var))

    def _compare(self, t0: int, t1: int, turned: float, var: float) -> None:
        """The course turned by `turned` (variance var) from t0 to t1: how far each lag's
        gyro interval disagrees."""
        if len(self._stamps) < 2 or t0 + LAGS_S[0] * 1e9 < self._stamps[0]:
            return                          # the gyro does not cover every lag: skip it
        stamps = np.fromiter(self._stamps, float, len(self._stamps))
        yaws = np.fromiter(self._yaws, float, len(self._yaws))
        lags = LAGS_S * 1e9
        gyro = np.interp(t1 + lags, stamps, yaws) - np.interp(t0 + lags, stamps, yaws)
        miss = turned - gyro
        if self._t is not None:
            self._sse *= math.exp(-(t1 - self._t) * 1e-9 / TAU_S)
        self._t = t1
        self._sse += miss * miss / var
        self._late = None

    @property
    def late_s(self) -> float:
        """How late the IMU's stamps look (s), 0 until the fixes point at a lag clearly."""
        if self._late is None:
            self._late = self._fit()
        return self._late

    def _fit(self) -> float:
        sse = self._sse
        i = int(np.argmin(sse))
        if sse[_ZERO_LAG] - sse[i] < SIGNIFICANT_CHI2:
            return 0.0
        late = float(LAGS_S[i])
        if 0 < i < len(sse) - 1:              # the parabola through the best three
            den = sse[i - 1] - 2.0 * sse[i] + sse[i + 1]
            if den > 0.0:
                late += 0.5 * float(LAGS_S[1] - LAGS_S[0]) * (sse[i - 1] - sse[i + 1]) / den
        return late if abs(late) >= SIGNIFICANT_S else 0.0

    @property
    def offset_s(self) -> float | None:
        """The IMU time offset to set (t_true = t_stamped + offset) when the fixes point
        at one clearly; else None."""
        late = self.late_s
        return -late if late else None
