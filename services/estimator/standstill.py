"""Is the car standing? And while it stands, what the gyro reads is its bias.

The car stands when, for more than `STILL_S`, the gyro is quiet, the specific force is
gravity's reaction (its size g and vertical: a car pulling away gently barely changes |f|
but tilts f off the vertical) and, once there is a position, GNSS and the filter both say
the speed is below `still_speed_mps`: a car pulling away smoothly looks quiet to an IMU,
and the filter's own speed alone would let a zero-velocity update hold itself.

"Quiet" depends on the IMU and on the car: a Razor on a silent electric car reads a few
thousandths of a rad/s, a cheaper IMU on an idling engine much more. Unless the settings
fix them, the thresholds are learnt from the first `align_s` of samples, taken while the
car stands (as alignment does): `QUIET_K` times their spread, never below the Razor's
figures (the floors) nor above a moving car's (the ceilings).
Equations: docs/estimator.md#standstill-and-gyro-bias.
"""
from __future__ import annotations

import math

from viena.services.estimator.settings import EstimatorSettings

#: the car must look still this long before it counts as standing
STILL_S = 1.0
#: time constants: the IMU figures' smoothing, and the gyro bias's pull while standing
_SMOOTH_S = 0.5
_BIAS_TAU_S = 5.0
#: learnt thresholds: this many times the parked spread, within these bounds (rms)
QUIET_K = 3.0
GYRO_FLOOR_RADPS, GYRO_CEILING_RADPS = 0.01, 0.05
ACCEL_FLOOR_MPS2, ACCEL_CEILING_MPS2 = 0.2, 1.0


class Standstill:
    def __init__(self, settings: EstimatorSettings, learnt: tuple = (None, None)):
        """`learnt`: thresholds learnt by an earlier Standstill (a reset keeps them)."""
        self.gyro_rms = settings.still_gyro_radps or learnt[0]       # None: to be learnt
        self.accel_rms = settings.still_accel_mps2 or learnt[1]
        self._learn_s = settings.align_s
        self._sums = [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self._t_learnt = 0.0
        self.max_bias = math.radians(settings.max_gyro_bias_dps)
        self._g2 = self._a2 = 1.0         # smoothed squares of the IMU figures
        self._still_s = 0.0              # how long it has looked still

    @property
    def still(self) -> bool:
        return self._still_s > STILL_S

    @property
    def thresholds(self) -> tuple[float | None, float | None]:
        """(gyro rms rad/s, specific force rms m/s^2) below which the IMU is quiet."""
        return self.gyro_rms, self.accel_rms

    def _learn(self, dt, gx, gy, gz, fx, fy, fz) -> None:
        """Gather the spread of the first seconds' samples; then set the thresholds."""
        s = self._sums
        s[0] += 1
        for i, v in enumerate((gx, gy, gz, fx, fy, fz)):
            s[1 + i] += v
            s[7 + i] += v * v
        self._t_learnt += dt
        if self._t_learnt < self._learn_s or s[0] < 10:
            return
        n = s[0]
        var = [s[7 + i] / n - (s[1 + i] / n) ** 2 for i in range(6)]
        gyro = QUIET_K * math.sqrt(max(0.0, sum(var[:3])))
        accel = QUIET_K * math.sqrt(max(0.0, sum(var[3:])))
        if self.gyro_rms is None:
            self.gyro_rms = min(GYRO_CEILING_RADPS, max(GYRO_FLOOR_RADPS, gyro))
        if self.accel_rms is None:
            self.accel_rms = min(ACCEL_CEILING_MPS2, max(ACCEL_FLOOR_MPS2, accel))
        # the smoothed figures start from what the first seconds showed
        self._g2, self._a2 = sum(var[:3]), sum(var[3:])

    def update(self, dt, gx, gy, gz, fx, fy, fz, rot, gravity, speed_still, attitude) -> None:
        """One IMU sample: rate (bias-corrected) and specific force in body axes; `rot` the
        body -> ENU rotation; `speed_still`: None before position is known, else whether
        GNSS and filter agree the car stands. Learns the gyro bias into `attitude`."""
        if dt <= 0.0:
            return
        if self.gyro_rms is None or self.accel_rms is None:
            self._learn(dt, gx, gy, gz, fx, fy, fz)
            return
        k = dt / (_SMOOTH_S + dt)
        self._g2 += k * (gx * gx + gy * gy + gz * gz - self._g2)
        r = rot
        fe = r[0] * fx + r[1] * fy + r[2] * fz
        fn = r[3] * fx + r[4] * fy + r[5] * fz
        # (|f| - g)^2 without the root: |f|^2 - g^2 = (|f| - g)(|f| + g) ~ 2 g (|f| - g)
        da = (fx * fx + fy * fy + fz * fz - gravity * gravity) / (2.0 * gravity)
        self._a2 += k * (da * da + fe * fe + fn * fn - self._a2)
        quiet = self._g2 < self.gyro_rms ** 2 and self._a2 < self.accel_rms ** 2
        if quiet and speed_still is not None:
            quiet = speed_still
        if quiet:
            self._still_s += dt
            if self._still_s > STILL_S and attitude.aligned:
                # the car stands: what the gyro reads is its bias (gx.. are already corrected)
                kb, lim = dt / _BIAS_TAU_S, self.max_bias
                b = attitude.gyro_bias
                b[0] = max(-lim, min(lim, b[0] + kb * gx))
                b[1] = max(-lim, min(lim, b[1] + kb * gy))
                b[2] = max(-lim, min(lim, b[2] + kb * gz))
        else:
            self._still_s = 0.0
