"""Is the car standing? And while it stands, what the gyro reads is its bias.

The car stands when, for more than `STILL_S`, the gyro is quiet, the specific force is
gravity's reaction (its size g and vertical: a car pulling away gently barely changes |f|
but tilts f off the vertical) and, once there is a position, GNSS and the filter both say
the speed is below `still_speed_mps`: a car pulling away smoothly looks quiet to an IMU,
and the filter's own speed alone would let a zero-velocity update hold itself. Before
there is a position, the receivers' Doppler speeds (doppler.py, admitted or not) outrank
the IMU: while every receiver heard reports more than `moving_mps` the car does not stand,
however quiet the IMU (a smooth straight is quiet). `moving_mps` is twice the admission's
`admit_max_drift_mps`, so that a receiver reporting a speed while the car stands still
fails the admission's drift check.

"Quiet" depends on the IMU and on the car: a Razor on a silent electric car reads a few
thousandths of a rad/s, a cheaper IMU on an idling engine much more. Unless the settings
fix them, the thresholds are learnt from `align_s` of samples taken while the car stands:
`QUIET_K` times their spread, never below the Razor's figures (the floors) nor above a
moving car's (the ceilings). A zero-velocity detector must not be trained on motion (an
estimator restarted mid-drive would learn a moving car's figures, and then call a smooth
straight standing), so GNSS says when: a window in which a receiver reports a speed of
`still_speed_mps` or more is thrown away and learning starts again, judging by the floors
meanwhile. Thresholds learnt before any receiver reported a speed (an IMU alone, parked
or not) hold until the first speed comes: a car standing then confirms them, a moving one
sends them back to the floors until it stands.
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
    def __init__(self, settings: EstimatorSettings, learnt: tuple = (None, None, False)):
        """`learnt`: thresholds learnt by an earlier Standstill, and whether GNSS said the
        car stood then (a reset keeps them: `learnt` of the old one)."""
        s = settings
        self._set = (bool(s.still_gyro_radps), bool(s.still_accel_mps2))
        self.gyro_rms = s.still_gyro_radps or learnt[0]              # None: to be learnt
        self.accel_rms = s.still_accel_mps2 or learnt[1]
        self.confirmed = all(self._set) or learnt[2]    # GNSS said the car stood as they were learnt
        self.still_mps = s.still_speed_mps
        self.moving_mps = max(s.still_speed_mps, 2.0 * s.admit_max_drift_mps)
        self.gnss_moving = False         # every receiver heard reports more than moving_mps
        self._learn_s = s.align_s
        self._restart_learning()         # the window's sums: n, sums and squares of six figures
        self._t_seen = 0.0               # IMU time seen while learning (the first align_s only gather)
        self.max_bias = math.radians(s.max_gyro_bias_dps)
        self._g2 = self._a2 = 1.0         # smoothed squares of the IMU figures
        self._still_s = 0.0              # how long it has looked still

    @property
    def still(self) -> bool:
        return self._still_s > STILL_S

    @property
    def thresholds(self) -> tuple[float | None, float | None]:
        """(gyro rms rad/s, specific force rms m/s^2) below which the IMU is quiet."""
        return self.gyro_rms, self.accel_rms

    @property
    def learnt(self) -> tuple:
        """What a reset keeps: the thresholds, and whether GNSS confirmed them."""
        return self.gyro_rms, self.accel_rms, self.confirmed

    def _forget(self) -> None:
        """Thresholds learnt from the IMU alone turn out to be a moving car's: learn again."""
        if not self._set[0]:
            self.gyro_rms = None
        if not self._set[1]:
            self.accel_rms = None
        self._t_seen = self._learn_s                  # judge by the floors meanwhile
        self._restart_learning()

    def _restart_learning(self) -> None:
        self._sums = [0] + [0.0] * 12
        self._t_learnt = 0.0
        self._gnss_parked = False        # a receiver said the car stood during the window

    def _learn(self, dt, gx, gy, gz, fx, fy, fz, parked: bool | None) -> bool:
        """Gather the spread of `align_s` of samples a standing car's (`parked`: what GNSS
        says, None: nothing); then set the thresholds and return True."""
        if parked is False:                 # a moving car's samples: start again
            self._restart_learning()
            return False
        self._gnss_parked = self._gnss_parked or bool(parked)
        s = self._sums
        s[0] += 1
        for i, v in enumerate((gx, gy, gz, fx, fy, fz)):
            s[1 + i] += v
            s[7 + i] += v * v
        self._t_learnt += dt
        if self._t_learnt < self._learn_s or s[0] < 10:
            return False
        n = s[0]
        var = [s[7 + i] / n - (s[1 + i] / n) ** 2 for i in range(6)]
        gyro = QUIET_K * math.sqrt(max(0.0, sum(var[:3])))
        accel = QUIET_K * math.sqrt(max(0.0, sum(var[3:])))
        if self.gyro_rms is None:
            self.gyro_rms = min(GYRO_CEILING_RADPS, max(GYRO_FLOOR_RADPS, gyro))
        if self.accel_rms is None:
            self.accel_rms = min(ACCEL_CEILING_MPS2, max(ACCEL_FLOOR_MPS2, accel))
        self.confirmed = self._gnss_parked
        # the smoothed figures start from what the parked seconds showed
        self._g2, self._a2 = sum(var[:3]), sum(var[3:])
        return True

    def update(self, dt, gx, gy, gz, fx, fy, fz, rot, gravity, speed_still, attitude, doppler=None) -> None:
        """One IMU sample: rate (bias-corrected) and specific force in body axes; `rot` the
        body -> ENU rotation; `speed_still`: None before position is known, else whether
        GNSS and filter agree the car stands; `doppler`: (slowest, fastest) speed the
        receivers heard lately report, used or not, or None. Learns the gyro bias into
        `attitude`."""
        parked = None if doppler is None else doppler[1] < self.still_mps
        self.gnss_moving = doppler is not None and doppler[0] > self.moving_mps
        if dt <= 0.0:
            return
        if self.gyro_rms is None or self.accel_rms is None:
            self._t_seen += dt
            if self._learn(dt, gx, gy, gz, fx, fy, fz, parked) or self._t_seen <= self._learn_s:
                return
        elif not self.confirmed and parked is not None:
            if parked:
                self.confirmed = True
            else:
                self._forget()
        gyro_rms = self.gyro_rms or GYRO_FLOOR_RADPS
        accel_rms = self.accel_rms or ACCEL_FLOOR_MPS2
        k = dt / (_SMOOTH_S + dt)
        self._g2 += k * (gx * gx + gy * gy + gz * gz - self._g2)
        r = rot
        fe = r[0] * fx + r[1] * fy + r[2] * fz
        fn = r[3] * fx + r[4] * fy + r[5] * fz
        # (|f| - g)^2 without the root: |f|^2 - g^2 = (|f| - g)(|f| + g) ~ 2 g (|f| - g)
        da = (fx * fx + fy * fy + fz * fz - gravity * gravity) / (2.0 * gravity)
        self._a2 += k * (da * da + fe * fe + fn * fn - self._a2)
        quiet = self._g2 < gyro_rms * gyro_rms and self._a2 < accel_rms * accel_rms
        if quiet and speed_still is not None:
            quiet = speed_still
        elif quiet and self.gnss_moving:        # no position yet: the receivers' speeds outrank the IMU
            quiet = False
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
