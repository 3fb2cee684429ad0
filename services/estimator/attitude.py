"""The car's attitude: Madgwick's filter, and who corrects its tilt when.

- alignment: at start (and after a long gap, when another IMU takes over, or when GNSS
  has disagreed for long) the specific force, rate and field are averaged over `align_s`,
  the car's own acceleration taken off when it moves; roll and pitch come from the mean
  specific force, yaw from the field if it is plausible; a still gyro's mean reading is
  its bias;
- then per IMU sample, Madgwick's step (MARG when a plausible magnetometer reading is
  there, else IMU-only) with the gyro's bias removed. Its gain says who corrects the tilt:
  * standing (or nothing tells the car's own acceleration): the accelerometer (minus the
    bias the Kalman filter learnt) levels the attitude, gain `madgwick_beta`;
  * moving, GNSS velocity coming: the Kalman filter's tilt states do, from how the
    velocity goes wrong (kalman.py), and hand their estimate over (`correct_tilt`);
    Madgwick only integrates the gyro (`madgwick_beta_aided`, 0), the yaw is corrected by
    the heading filter (course, magnetometer);
  * moving without GNSS velocity: the accelerometer minus the turn's centripetal part
    levels it slowly (`madgwick_beta_coast`).
  Madgwick's step is normalised: any steady disagreement moves the attitude at full
  speed, so it may only be fed a "down" that is right on average *at every moment*;
  the car's own acceleration between GNSS fixes is not that, hence the split.
- the reported roll and pitch variance is the Kalman filter's, or before it has one, how
  much the accelerometer disagrees.

Plain floats: this runs for every IMU sample. Equations: docs/estimator.md#attitude-madgwick-filter.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from viena.common.rotation import wrap_angle
from viena.services.estimator.angles import tilt_from_specific_force
from viena.services.estimator.heading import UNKNOWN_VAR
from viena.services.estimator.madgwick import Madgwick, attitude_from_vectors
from viena.services.estimator.settings import EstimatorSettings

_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
GRAVITY = 9.80665
#: a car stands when its specific force is gravity's size, steady, to this (m/s^2) ...
STILL_NORM_MPS2 = 0.3
#: ... otherwise, with its speed unknown, the tilt found may be off by a car's acceleration
#: over gravity (3 m/s^2: 17 deg; 10 deg is a hard acceleration or a bend at speed)
MOVING_ALIGN_SIGMA_DEG = 10.0
#: a moving car with no known speed waits this long (s) for one before aligning anyway
ALIGN_WAIT_S = 30.0


class Attitude:
    """Madgwick's filter and what it is fed. `rot` is the body -> ENU rotation (row-major
    9 floats), `rate` the bias-corrected gyro, `gyro_bias` what is taken off the gyro."""

    def __init__(self, settings: EstimatorSettings, counts: dict, log: logging.Logger):
        s = self.settings = settings
        self.counts, self.log = counts, log
        self.beta, self.beta_coast = s.madgwick_beta, s.madgwick_beta_coast
        self.beta_aided = s.madgwick_beta_aided
        self.declination = math.radians(s.mag_declination_deg)
        self.use_mag = s.use_magnetometer
        field = np.asarray(s.mag_field_nT, float) * 1e-9
        norm = float(np.linalg.norm(field))
        dip = math.asin(-field[2] / norm)                    # positive down
        tol, dip_tol = s.mag_norm_tolerance, math.radians(s.mag_dip_tolerance_deg)
        self._mag_bounds = (((1 - tol) * norm) ** 2, ((1 + tol) * norm) ** 2,
                            math.sin(max(0.0, dip - dip_tol)), math.sin(min(0.5 * math.pi, dip + dip_tol)))
        self.att = Madgwick(self.beta, self.declination)
        self.aligned = False
        self.mag_heading = False             # the magnetometer gave the yaw
        self.gyro_bias = [0.0, 0.0, 0.0]
        self.rot = _IDENTITY
        self.rate = (0.0, 0.0, 0.0)
        self.tilt_var = [UNKNOWN_VAR, UNKNOWN_VAR]    # about the forward and the right axis
        self._down = (0.0, 0.0, 1.0)         # the last motion-compensated specific force
        self._realign()

    @property
    def yaw(self) -> float:
        """Yaw of the attitude as the filters use it: atan2(R[1,0], R[0,0])."""
        r = self.rot
        return math.atan2(r[3], r[0])

    def _realign(self) -> None:
        self.aligned = False
        self._align_known = True
        self._align_sq = 0.0
        self._align_waited = 0.0            # moving, speed unknown: windows thrown away (s)
        self._new_window()
        self._align_speed = (0.0, 0.0)      # the speed at the first and the last sample
        self._align_moving = False          # the receivers' speeds said the car moved (doppler.py)

    def _new_window(self) -> None:
        """Alignment starts gathering again, from the next sample."""
        self._align = [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0]  # n, f, w, m, n_mag
        self._align_t0: int | None = None

    def realign(self) -> None:
        """Roll and pitch are no longer to be trusted (a long gap, another IMU, GNSS disagreeing
        for long): align again."""
        self._realign()

    # -- alignment -----------------------------------------------------------------------------
    def gather(self, t: int, fx, fy, fz, gx, gy, gz, mag, keep_yaw: bool, speed: float = 0.0,
               speed_known: bool = True, gnss_moving: bool = False) -> None:
        """Average the specific force (and field, rate) over align_s, then set the attitude;
        `keep_yaw`: a realignment keeps the yaw that the heading filter knew; `speed`: the
        car's (GNSS) speed, when it realigns while driving: the turn's acceleration
        (w x v, as in `update`) and the change of speed over align_s come off the specific
        force, and the gyro's mean is a turn, not its bias. `speed_known`: the filter's
        speed is known well (GNSS velocity); else its change is not taken off, and unless
        the car plainly stood, the tilt found is only as good as a car's acceleration
        allows (`MOVING_ALIGN_SIGMA_DEG`). `gnss_moving`: the receivers, used or not yet,
        all report a speed (standstill.py): the car did not stand, however plainly the IMU
        says it did (a smooth straight reads like a car parked)."""
        if self._align_t0 is not None and speed_known and not self._align_known and self._align_moving:
            # a window that cannot align (the car moved, its speed unknown): its speed is
            # known from now, so a new one starts now rather than at this one's end
            self._new_window()
        a = self._align
        if self._align_t0 is None:
            self._align_t0 = t
            self._align_speed = (speed, speed)
            self._align_known = speed_known
            self._align_moving = gnss_moving
        else:
            self._align_speed = (self._align_speed[0], speed)
            self._align_known = self._align_known and speed_known
            self._align_moving = self._align_moving or gnss_moving
        if a[0] == 0:
            self._align_sq = 0.0
        self._align_sq += fx * fx + fy * fy + fz * fz
        a[0] += 1
        fx, fz = fx + gz * speed, fz - gx * speed
        a[1:4] = [a[1] + fx, a[2] + fy, a[3] + fz]
        a[4:7] = [a[4] + gx, a[5] + gy, a[6] + gz]
        if mag is not None:
            a[7:11] = [a[7] + mag[0], a[8] + mag[1], a[9] + mag[2], a[10] + 1]
        span_s = (t - self._align_t0) * 1e-9
        if span_s >= self.settings.align_s:
            self._window_done(span_s, keep_yaw)

    def _window_done(self, span_s: float, keep_yaw: bool) -> None:
        """A window of align_s gathered: the attitude from its means, unless the car moved
        at a speed nobody knows (then another window, for a while)."""
        s, a = self.settings, self._align
        n = a[0]
        v0, v1 = self._align_speed
        known = self._align_known
        f = (a[1] / n, a[2] / n - ((v1 - v0) / span_s if known else 0.0), a[3] / n)
        w = (a[4] / n, a[5] / n, a[6] / n)
        m = (a[7] / a[10], a[8] / a[10], a[9] / a[10]) if a[10] else None
        lim = math.radians(s.max_gyro_bias_dps)
        # the car stood (or its speed was known and its acceleration came off): 1 deg;
        # else the mean specific force holds the car's own acceleration, unknown. With its
        # speed not known, the IMU says whether it stood, unless the receivers (used or
        # not yet) say it moved: a smooth straight reads like a stop
        norm = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
        spread = math.sqrt(max(0.0, self._align_sq / n - (a[1] ** 2 + a[2] ** 2 + a[3] ** 2) / (n * n)))
        quiet = (abs(norm - GRAVITY) < STILL_NORM_MPS2 and spread < STILL_NORM_MPS2
                 and math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) < lim)
        stood = (known and max(v0, v1) < s.still_speed_mps) or (not known and quiet and not self._align_moving)
        if not (stood or known) and self._align_waited < ALIGN_WAIT_S:
            # a moving car whose speed nobody knows yet: wait for GNSS's (a car accelerating
            # at 1.4 m/s^2 would be aligned 8 deg pitched), or align anyway after a while
            self._align_waited += span_s
            self._new_window()
            return
        if stood and max(v0, v1) < s.still_speed_mps and math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) < lim:
            self.gyro_bias = [max(-lim, min(lim, self.gyro_bias[k] + w[k])) for k in range(3)]
        use_mag = m is not None and self.use_mag and self.mag_plausible(m, *f)
        yaw = self.yaw
        self.att.set_quaternion(attitude_from_vectors(f, m if use_mag else None, self.declination))
        if keep_yaw:                         # realigning roll/pitch after a gap: keep the yaw
            r = _rotation(self.att)
            self.att.rotate_world_z(wrap_angle(yaw - math.atan2(r[3], r[0])))
        self.rot = _rotation(self.att)
        self.mag_heading = use_mag
        self.aligned = True
        self._align_waited = 0.0
        sigma = 1.0 if stood or known else MOVING_ALIGN_SIGMA_DEG
        self.tilt_var = [math.radians(sigma) ** 2] * 2
        pitch, roll = tilt_from_specific_force(*f)
        self.log.info("attitude aligned over %d samples: roll %.2f pitch %.2f deg%s", n,
                      math.degrees(roll), math.degrees(pitch),
                      ", yaw from the magnetometer" if use_mag else "")

    # -- per sample ----------------------------------------------------------------------------
    def update(self, dt: float, ax, ay, az, gx, gy, gz, mag, speed, aided: bool, still: bool) -> None:
        """One Madgwick step with the bias-corrected rate (gx, gy, gz) and specific force
        (ax, ay, az: the accelerometer minus the Kalman filter's bias estimate, which its
        tilt states keep apart from the tilt; levelling with the raw one would put the
        learnt bias back into the tilt, and the two would count it twice). `speed`: the filter's
        velocity along the car's forward axis when position and yaw are known (else None);
        `aided`: GNSS velocity came within the last second; `still`: the car stands."""
        if still or speed is None:
            beta, mx, mz = (self.beta if still else self.beta_coast), 0.0, 0.0
        elif aided:
            beta, mx, mz = self.beta_aided, 0.0, 0.0
        else:
            # a car moves along its forward axis: body velocity (0, s, 0), so the turn's
            # acceleration is w x v_b = (-w_z s, 0, w_x s); the change of s would only echo
            # the attitude back to itself without GNSS
            beta, mx, mz = self.beta_coast, -gz * speed, gx * speed
        att = self.att
        att.beta = beta
        if dt > 0.0:
            ux, uy, uz = ax - mx, ay, az - mz
            if beta > 0.0 and mag is not None and self.use_mag and self.mag_plausible(mag, ux, uy, uz):
                att.update_marg(gx, gy, gz, ux, uy, uz, mag[0], mag[1], mag[2], dt)
                self.mag_heading = True
            else:
                att.update_imu(gx, gy, gz, ux, uy, uz, dt)
            self._down = (ux, uy, uz)
        self.rot = _rotation(att)

    def correct_tilt(self, east_rad: float, north_rad: float) -> None:
        """Turn the attitude by the Kalman filter's tilt estimate, about East and North."""
        if east_rad or north_rad:
            self.att.rotate_world(east_rad, north_rad, 0.0)
            self.rot = _rotation(self.att)

    def mag_plausible(self, m, fx, fy, fz) -> bool:
        """Earth's field has a known strength and dip; a motor's or a magnet's has not.
        (Compared squared, without roots: this runs for every sample.)"""
        mx, my, mz = m
        m2 = mx * mx + my * my + mz * mz
        lo2, hi2, s_lo, s_hi = self._mag_bounds
        ok = lo2 <= m2 <= hi2
        if ok:
            # sin(dip) = -(m . f) / (|m| |f|), f pointing up; dip within its tolerance
            c = -(mx * fx + my * fy + mz * fz)
            mf2 = m2 * (fx * fx + fy * fy + fz * fz)
            ok = c > 0.0 and s_lo * s_lo * mf2 <= c * c <= s_hi * s_hi * mf2
        if not ok:
            self.counts["mag_rejected"] += 1
        return ok

    def tilt_residual(self, dt: float) -> None:
        """Mean square of the tilt the (motion-compensated) accelerometer disagrees with,
        over ~10 s: what the attitude's roll and pitch variance are reported as."""
        r = self.rot
        ux, uy, uz = self._down
        n = math.sqrt(ux * ux + uy * uy + uz * uz)
        if n == 0.0:
            return
        # gravity's reaction as the attitude sees it is R^T [0, 0, 1] = third row of R
        ex = r[6] - ux / n
        ey = r[7] - uy / n
        k = min(1.0, dt / 10.0)
        v = self.tilt_var
        v[0] += k * (ex * ex - v[0])      # about the forward axis: roll
        v[1] += k * (ey * ey - v[1])      # about the right axis: pitch

    def rotate_yaw(self, angle_rad: float) -> None:
        """Turn the attitude about the world up axis (a yaw correction)."""
        self.att.rotate_world_z(angle_rad)
        self.rot = _rotation(self.att)


def _rotation(att: Madgwick) -> tuple:
    """Body -> ENU rotation matrix of the attitude, row-major 9-tuple."""
    w, x, y, z = att.q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def rotate(r, v):
    """r v for a row-major 9-tuple r."""
    return (r[0] * v[0] + r[1] * v[1] + r[2] * v[2],
            r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
            r[6] * v[0] + r[7] * v[1] + r[8] * v[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
