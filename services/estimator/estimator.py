"""The estimator: attitude, position and velocity from IMU samples and GNSS fixes.

A plain class, no zenoh: feed it samples as dicts in the agreed schemas (viena.imu.sample/1,
viena.gnss.fix/1), read `state()`. The same code runs in the live service and offline
over a recording:

    est = Estimator({"origin": [38.7369, -9.1395, 100.0]})
    for sample in merged_by_time(imu_samples, gnss_fixes):
        est.add_imu(sample) if "accel_mps2" in sample else est.add_gnss(sample)
    est.state()["enu_m"]

How the parts fit (see README.md for the why):
- attitude: Madgwick (MARG when a plausible magnetometer reading is there, else IMU-only),
  fed the accelerometer minus the car's own acceleration, which the Kalman filter's
  GNSS-tied velocity tells us; yaw from the GNSS course over ground when moving;
- position/velocity: `NavKalman`, driven by the specific force rotated to ENU minus
  gravity, corrected by GNSS position and velocity at the antenna (lever arm), by the car's
  non-holonomic constraint and by zero velocity at standstill;
- time: samples are used in the order of their acquisition time `t`. IMU samples must come
  in order (older ones are dropped and counted); a GNSS fix is late by its latency, so it
  is compared with the state *at its own time*, kept for the last `late_window_s`; a fix
  from the IMU's future waits until the IMU passes it;
- bad input is rejected and counted before it reaches a filter; a filter that diverges
  is reset, says why, and realigns.
"""
from __future__ import annotations

import heapq
import logging
import math
from typing import Callable

import numpy as np

from viena.common.config import merge_settings
from viena.common.rotation import euler_from_quat, wrap_angle
from viena.common.geodesy import LocalFrame
from viena.services.estimator.heading import UNKNOWN_VAR, HeadingFilter, course_yaw
from viena.services.estimator.history import TrajectoryHistory
from viena.services.estimator.inputs import Fix, ImuLimits, Rejected, gnss_fix, imu_values
from viena.services.estimator.kalman import Diverged, KalmanNoise, NavKalman
from viena.services.estimator.madgwick import Madgwick, attitude_from_vectors
from viena.services.estimator.navigation import waypoint_guidance

#: Settings (the [estimator] table of the TOML file); the type of each default is the type.
DEFAULTS: dict = {
    # frames
    "origin": [],                       # [lat_deg, lon_deg, height_m]; [] = the first good fix
    "gnss_lever_arm_m": {},             # unit -> antenna [x right, y forward, z up] from body origin
    "default_lever_arm_m": [0.0, 0.0, 0.0],
    # attitude
    "align_s": 1.0,                     # IMU time averaged for the initial roll/pitch (car still)
    "madgwick_beta": 0.01,              # rad/s
    "madgwick_beta_coast": 0.001,       # rad/s, while GNSS velocity is missing
    "motion_tau_s": 0.3,                # smoothing of the car's acceleration for Madgwick
    "use_magnetometer": True,
    "mag_declination_deg": -2.48,       # positive east; Lisbon 2017 is 2.48 deg WEST
    "mag_field_nT": [-1121.5, 26479.8, -34884.7],   # expected field, ENU, to reject disturbances
    "mag_norm_tolerance": 0.15,         # relative
    "mag_dip_tolerance_deg": 5.0,
    "course_heading": True,             # yaw from the GNSS course over ground when moving
    "course_min_speed_mps": 1.0,
    "gyro_noise_psd": 1e-6,             # (rad/s)^2/Hz
    "gyro_bias_walk_psd": 1e-9,         # (rad/s)^2/s
    # position and velocity
    "accel_psd": 0.05,                  # (m/s^2)^2/Hz, accelerometer noise plus tilt errors
    "accel_bias_walk_psd": 1e-6,        # (m/s^2)^2/s
    "free_accel_psd": 4.0,              # (m/s^2)^2/Hz when the IMU cannot drive the prediction
    "constraint_interval_s": 0.1,       # non-holonomic / zero-velocity updates
    "nonholonomic": True,               # the car does not slide sideways nor jump
    "nhc_sigma_mps": 0.1,
    "zupt_sigma_mps": 0.02,
    "still_gyro_radps": 0.01,           # standstill: gyro rms below this ...
    "still_accel_mps2": 0.2,            # ... and specific force this close to gravity ...
    "still_speed_mps": 0.3,             # ... and GNSS and filter speeds below this
    "gate_chi2": 16.27,                 # innovation test, 3 dof, 99.9 %
    "max_pos_sigma_m": 50.0,
    "vel_sigma_default_mps": 0.2,       # when a fix carries velocity without sigmas
    "use_vel_latency": True,            # the fix's velocity is vel_latency_s older than t
    "gnss_reset_s": 5.0,                # good fixes rejected this long: trust GNSS, reinitialise
    "gnss_max_rate_hz": 10.0,           # per receiver; 0 = every fix (see README)
    # time
    "late_window_s": 1.0,               # how late a GNSS fix may be and still be used
    "imu_timeout_s": 0.5,               # IMU silent this long: not live
    "imu_gap_s": 0.2,                   # larger steps between IMU samples are not integrated
    "gnss_timeout_s": 2.0,
    "max_future_s": 2.0,                # inputs further ahead of the clock are rejected
    # input limits
    "max_accel_g": 16.0,
    "max_gyro_dps": 2000.0,
}

_G = 9.80665
#: zero velocity: the velocity states, directly
_ZUPT_H = np.zeros((3, 9))
_ZUPT_H[:, 3:6] = np.eye(3)
_REALIGN_GAP_S = 2.0
#: this many inputs in a row refused for their time (late, or an hour ahead offline) mean
#: the earlier times were wrong, not these
_TIMELINE_RESTART = 200


class Estimator:
    """Feed `add_imu(sample)` and `add_gnss(fix)`; read `state()`. Not thread-safe: one
    thread feeds it (the service's worker)."""

    def __init__(self, settings: dict | None = None, clock: Callable[[], int] | None = None,
                 log: logging.Logger | None = None):
        s = self.settings = merge_settings(DEFAULTS, settings or {}, "estimator settings")
        self.log = log or logging.getLogger("viena.estimator")
        self._clock = clock
        self._limits = ImuLimits(s["max_accel_g"] * _G, math.radians(s["max_gyro_dps"]))
        self._beta = s["madgwick_beta"]
        self._beta_coast = s["madgwick_beta_coast"]
        self._declination = math.radians(s["mag_declination_deg"])
        field = np.asarray(s["mag_field_nT"], float) * 1e-9
        self._mag_norm = float(np.linalg.norm(field))
        self._mag_dip = math.asin(-field[2] / self._mag_norm)       # positive down
        tol, dip_tol = s["mag_norm_tolerance"], math.radians(s["mag_dip_tolerance_deg"])
        self._mag_bounds = (((1 - tol) * self._mag_norm) ** 2, ((1 + tol) * self._mag_norm) ** 2,
                            math.sin(max(0.0, self._mag_dip - dip_tol)),
                            math.sin(min(0.5 * math.pi, self._mag_dip + dip_tol)))
        self._late_ns = int(s["late_window_s"] * 1e9)
        self._imu_timeout_ns = int(s["imu_timeout_s"] * 1e9)
        self._gnss_timeout_ns = int(s["gnss_timeout_s"] * 1e9)
        self._future_ns = int(s["max_future_s"] * 1e9)
        self._imu_gap_s = s["imu_gap_s"]
        self._use_mag = s["use_magnetometer"]
        self._vel_latency = s["use_vel_latency"]
        self._nhc, self._nhc_var = s["nonholonomic"], s["nhc_sigma_mps"] ** 2
        self._zupt_R = np.eye(3) * s["zupt_sigma_mps"] ** 2
        self._still_g2, self._still_a2 = s["still_gyro_radps"] ** 2, s["still_accel_mps2"] ** 2
        self._still_v = s["still_speed_mps"]
        self._constraint_ns = int(s["constraint_interval_s"] * 1e9)
        self._motion_tau = s["motion_tau_s"]
        self._lever_default = tuple(float(v) for v in s["default_lever_arm_m"])
        self._levers = {u: tuple(float(v) for v in arm) for u, arm in s["gnss_lever_arm_m"].items()}
        for arm in (self._lever_default, *self._levers.values()):
            if len(arm) != 3:
                raise ValueError("a lever arm is [x right, y forward, z up] in m")
        self._noise = KalmanNoise(s["accel_psd"], s["accel_bias_walk_psd"], s["free_accel_psd"])
        self.frame: LocalFrame | None = None
        self.origin_source = "none"
        if s["origin"]:
            if len(s["origin"]) != 3:
                raise ValueError("origin is [lat_deg, lon_deg, height_m]")
            self._set_origin(LocalFrame(*s["origin"]), "config")
        # counters, kept across resets
        self.counts = {"imu": 0, "gnss": 0, "gnss_decimated": 0, "imu_gaps": 0, "resets": 0,
                       "mag_rejected": 0, "nhc": 0, "zupt": 0, "course_used": 0}
        self.gnss_used = 0
        self.gnss_rejected: dict[str, int] = {}
        self.input_rejected: dict[str, int] = {}
        self.last_reset: str | None = None
        self.waypoint: tuple[float, float] | None = None
        self._seq = 0
        self._pending: list = []            # heap of (t, n, Fix) waiting for the IMU to pass
        self._pending_n = 0
        self._last_fix_t: dict[str, int] = {}     # last usable fix per unit
        self._used_fix_t: dict[str, int] = {}     # last fix used per unit (rate limit)
        rate = s["gnss_max_rate_hz"]
        # a fix due at the rate is used even if it comes a little early (5 ms of jitter)
        self._fix_interval_ns = int(1e9 / rate) - 5_000_000 if rate > 0 else 0
        self._t_imu: int | None = None      # last IMU sample used
        self.imu_unit: str | None = None    # the first unit heard; others are refused
        self._refused_in_a_row = 0
        self._t_state: int | None = None    # time of the state
        self._restart()

    # -- public ----------------------------------------------------------------------------
    def add_imu(self, sample) -> bool:
        """Use one viena.imu.sample/1; False if it was rejected (and counted)."""
        try:
            t, ax, ay, az, gx, gy, gz, mag = imu_values(sample, self._limits)
            self._check_future(t)
        except Rejected as exc:
            self._reject_input(exc.reason)
            return False
        unit = sample.get("unit")
        if unit != self.imu_unit:
            if type(unit) is not str:
                self._reject_input("malformed")
                return False
            if self.imu_unit is not None:
                # one IMU drives the filter; another takes over only when it has gone quiet
                if self._t_imu is not None and t - self._t_imu < self._imu_timeout_ns:
                    self._reject_input("imu_other_unit")
                    return False
                self._t_imu = None
                self._realign_attitude()
            self.imu_unit = unit
            self.log.info("IMU unit %s drives the estimator", unit)
        last = self._t_imu
        if last is not None and t <= last:
            self._reject_input("imu_late" if t < last else "imu_duplicate")
            self._refused_in_a_row += 1
            if self._refused_in_a_row >= _TIMELINE_RESTART:
                self._restart_timeline("IMU times went back")
            return False
        self._refused_in_a_row = 0
        self.counts["imu"] += 1
        dt = 0.0 if last is None else (t - last) * 1e-9
        self._t_imu = t
        try:
            self._imu_step(t, dt, ax, ay, az, gx, gy, gz, mag)
        except Diverged as exc:
            self._reset(f"diverged: {exc}")
        pending = self._pending
        while pending and pending[0][0] <= t:
            self._use_fix(heapq.heappop(pending)[2])
        return True

    def add_gnss(self, sample) -> bool:
        """Use one viena.gnss.fix/1; False if it was rejected as bad or late input.

        A well-formed fix that the filter refuses (no solution, large sigma, failed
        innovation test) returns True and is counted in `gnss_rejected`.
        """
        try:
            fix = gnss_fix(sample)
            self._check_future(fix.t)
        except Rejected as exc:
            self._reject_input(exc.reason)
            return False
        if self._t_state is not None and fix.t < self._t_state - self._late_ns:
            self._reject_input("gnss_late")
            return False
        self.counts["gnss"] += 1
        # the IMU went quiet: fixes waiting for it are used with the constant-velocity model
        while self._pending and self._pending[0][0] < fix.t - self._imu_timeout_ns:
            self._use_fix(heapq.heappop(self._pending)[2])
        if self._t_imu is not None and fix.t > self._t_imu and fix.t - self._t_imu < self._imu_timeout_ns:
            self._pending_n += 1
            heapq.heappush(self._pending, (fix.t, self._pending_n, fix))
        else:
            self._use_fix(fix)
        return True

    def set_waypoint(self, waypoint: tuple[float, float] | None) -> None:
        self.waypoint = None if waypoint is None else (float(waypoint[0]), float(waypoint[1]))

    @property
    def imu_live(self) -> bool:
        """An IMU sample came within imu_timeout_s of the state's time."""
        t = self._t_state
        return t is not None and self._t_imu is not None and t - self._t_imu < self._imu_timeout_ns

    @property
    def t(self) -> int | None:
        """Time of the state, ns UTC."""
        return self._t_state

    # -- life ------------------------------------------------------------------------------
    def _restart(self) -> None:
        """Forget the estimate (not the counters nor the origin): align again from scratch."""
        s = self.settings
        self.att = Madgwick(self._beta, self._declination)
        self.aligned = False
        self.kf = NavKalman(self._noise)
        self.heading = HeadingFilter(s["gyro_noise_psd"], s["gyro_bias_walk_psd"])
        self.mag_heading = False
        self.gyro_bias = [0.0, 0.0, 0.0]
        self._history = TrajectoryHistory(self._late_ns)
        self._align = [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0]   # n, f, w, m, n_mag
        self._align_t0: int | None = None
        self._rot = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self._rate = (0.0, 0.0, 0.0)
        self._vb = None                      # last body-frame velocity (motion compensation)
        self._ab = [0.0, 0.0, 0.0]           # smoothed body-frame d(v_b)/dt
        self._still_g = self._still_a = 1.0  # smoothed squares for the standstill test
        self._still_s = 0.0                  # how long it has been still
        self._tilt_var = [UNKNOWN_VAR, UNKNOWN_VAR]
        self._down = (0.0, 0.0, 1.0)         # the last motion-compensated specific force
        self._reject_since: int | None = None
        self._next_constraint_t = 0
        self._last_pseudo_t = 0              # pseudo-measurements last applied (with a fix)
        self._gnss_speed, self._gnss_speed_t = math.inf, None   # last measured GNSS speed

    def _reset(self, reason: str) -> None:
        self.counts["resets"] += 1
        self.last_reset = reason
        self.log.warning("estimator reset (%s): realigning", reason)
        self._restart()

    def _set_origin(self, frame: LocalFrame, source: str) -> None:
        self.frame, self.origin_source = frame, source
        self._gravity = frame.gravity_mps2
        self.log.info("ENU origin (%s): lat %.8f lon %.8f h %.3f", source, *frame.origin)

    _gravity = _G

    # -- IMU ---------------------------------------------------------------------------------
    def _imu_step(self, t, dt, ax, ay, az, gx, gy, gz, mag) -> None:
        if dt > self._imu_gap_s:
            self.counts["imu_gaps"] += 1
            if dt > _REALIGN_GAP_S:
                self._realign_attitude()
            dt = 0.0
        # the state's clock: after a GNSS-only spell it may be ahead of the IMU
        t_prev = self._t_state
        dt_state = 0.0 if t_prev is None else (t - t_prev) * 1e-9
        if dt_state < 0.0:
            dt_state = 0.0
        else:
            self._t_state = t
        b = self.gyro_bias
        gx, gy, gz = gx - b[0], gy - b[1], gz - b[2]
        self._rate = (gx, gy, gz)
        kx = self.kf.x
        fx, fy, fz = ax - kx[6], ay - kx[7], az - kx[8]
        self._standstill(gx, gy, gz, fx, fy, fz, dt)

        if not self.aligned:
            self._gather_alignment(t, fx, fy, fz, gx, gy, gz, mag)
            kf = self.kf
            if kf.initialized:
                if dt_state > 0.0:
                    kf.move(0.0, 0.0, 0.0, dt_state)
                self._history.append(t, kf.x, math.atan2(self._rot[3], self._rot[0]))
            return

        # the accelerometer minus the car's own acceleration is what tells Madgwick "down".
        # Not minus the filter's bias estimate: a tilt error and a horizontal bias look the
        # same to GNSS, and feeding one back into the other makes both drift together.
        mx, my, mz = self._motion_accel(t, dt, gx, gy, gz)
        ux, uy, uz = ax - mx, ay - my, az - mz
        if dt > 0.0:
            if mag is not None and self._use_mag and self._mag_plausible(mag, ux, uy, uz):
                self.att.update_marg(gx, gy, gz, ux, uy, uz, mag[0], mag[1], mag[2], dt)
                self.mag_heading = True
            else:
                self.att.update_imu(gx, gy, gz, ux, uy, uz, dt)
            self._down = (ux, uy, uz)
            self.heading.pending_s += dt
        r = self._rot = _rotation(self.att)
        yaw = math.atan2(r[3], r[0])

        kf = self.kf
        if not kf.initialized:
            return
        if dt_state > self._imu_gap_s:
            kf.move(0.0, 0.0, 0.0, dt_state)
        elif self.heading_valid:
            ae = r[0] * fx + r[1] * fy + r[2] * fz
            an = r[3] * fx + r[4] * fy + r[5] * fz
            au = r[6] * fx + r[7] * fy + r[8] * fz - self._gravity
            kf.move(ae, an, au, dt_state, r)
        else:
            # yaw unknown: the horizontal acceleration cannot be put in ENU; let GNSS lead
            au = r[6] * fx + r[7] * fy + r[8] * fz - self._gravity
            kf.move(0.0, 0.0, au, dt_state)
        if t >= self._next_constraint_t:
            self._next_constraint_t = t + self._constraint_ns
            self._tilt_residual(self._constraint_ns * 1e-9)
            if t - self._last_pseudo_t >= self._constraint_ns:
                self._constraints()
        self._history.append(t, kf.x, yaw)

    def _gather_alignment(self, t, fx, fy, fz, gx, gy, gz, mag) -> None:
        """Average the specific force (and field, gyro) over align_s, then set the attitude."""
        a = self._align
        if self._align_t0 is None:
            self._align_t0 = t
        a[0] += 1
        a[1] += fx; a[2] += fy; a[3] += fz
        a[4] += gx; a[5] += gy; a[6] += gz
        if mag is not None:
            a[7] += mag[0]; a[8] += mag[1]; a[9] += mag[2]; a[10] += 1
        if (t - self._align_t0) * 1e-9 < self.settings["align_s"]:
            return
        n = a[0]
        f = (a[1] / n, a[2] / n, a[3] / n)
        w = (a[4] / n, a[5] / n, a[6] / n)
        m = (a[7] / a[10], a[8] / a[10], a[9] / a[10]) if a[10] else None
        if math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) < self.settings["still_gyro_radps"]:
            self.gyro_bias = [self.gyro_bias[k] + w[k] for k in range(3)]
        use_mag = (m is not None and self.settings["use_magnetometer"]
                   and self._mag_plausible(m, *f))
        keep_yaw = self.heading.valid
        yaw = math.atan2(self._rot[3], self._rot[0])
        q = attitude_from_vectors(f, m if use_mag else None, self._declination)
        self.att.set_quaternion(q)
        if keep_yaw:                         # realigning roll/pitch after a gap: keep the yaw
            r = _rotation(self.att)
            self.att.rotate_world_z(wrap_angle(yaw - math.atan2(r[3], r[0])))
        self._rot = _rotation(self.att)
        self.mag_heading = use_mag
        self.aligned = True
        self._tilt_var = [math.radians(1.0) ** 2] * 2
        self.log.info("attitude aligned over %d samples: roll %.2f pitch %.2f deg%s", n,
                      math.degrees(euler_from_quat(q)[2]), math.degrees(euler_from_quat(q)[1]),
                      ", yaw from the magnetometer" if use_mag else "")

    def _realign_attitude(self) -> None:
        self.aligned = False
        self._align = [0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0]
        self._align_t0 = None
        self._vb = None

    def _motion_accel(self, t, dt, gx, gy, gz):
        """The car's acceleration in body axes: d(v_b)/dt + w x v_b, v_b from the filter.

        Between fixes the filter's velocity follows the IMU itself, so the first term adds
        nothing; what it adds is what GNSS corrected, which is exactly what the attitude got
        wrong. Without GNSS velocity it would only echo the attitude back to itself, so
        then only the turn's centripetal part is kept and the attitude leans on the gyro
        (a smaller Madgwick gain) until GNSS is back.
        """
        if not (self.kf.initialized and self.heading_valid):
            self._vb = None
            self.att.beta = self._beta
            return 0.0, 0.0, 0.0
        r = self._rot
        ve, vn, vu = self.kf.x[3], self.kf.x[4], self.kf.x[5]
        vbx = r[0] * ve + r[3] * vn + r[6] * vu
        vby = r[1] * ve + r[4] * vn + r[7] * vu
        vbz = r[2] * ve + r[5] * vn + r[8] * vu
        ab = self._ab
        aided = self._gnss_speed_t is not None and t - self._gnss_speed_t < 1_000_000_000
        if aided:
            self.att.beta = self._beta
        if not aided:
            ab[0] = ab[1] = ab[2] = 0.0
            self.att.beta = self._beta_coast
        elif self._vb is not None and dt > 0.0:
            k = dt / (self._motion_tau + dt)
            p = self._vb
            ab[0] += k * ((vbx - p[0]) / dt - ab[0])
            ab[1] += k * ((vby - p[1]) / dt - ab[1])
            ab[2] += k * ((vbz - p[2]) / dt - ab[2])
        self._vb = (vbx, vby, vbz)
        return (ab[0] + gy * vbz - gz * vby,
                ab[1] + gz * vbx - gx * vbz,
                ab[2] + gx * vby - gy * vbx)

    def _mag_plausible(self, m, fx, fy, fz) -> bool:
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

    def _tilt_residual(self, dt) -> None:
        """Mean square of the tilt the (motion-compensated) accelerometer disagrees with,
        over ~10 s: what the attitude's roll and pitch variance are reported as."""
        r = self._rot
        ux, uy, uz = self._down
        n = math.sqrt(ux * ux + uy * uy + uz * uz)
        if n == 0.0:
            return
        # gravity's reaction as the attitude sees it is R^T [0, 0, 1] = third row of R
        ex = r[6] - ux / n
        ey = r[7] - uy / n
        k = min(1.0, dt / 10.0)
        v = self._tilt_var
        v[0] += k * (ex * ex - v[0])      # about the forward axis: pitch
        v[1] += k * (ey * ey - v[1])      # about the right axis: roll

    def _standstill(self, gx, gy, gz, fx, fy, fz, dt) -> None:
        if dt <= 0.0:
            return
        k = dt / (0.5 + dt)
        self._still_g += k * (gx * gx + gy * gy + gz * gz - self._still_g)
        # a car pulling away gently barely changes |f|, but it tilts f off the vertical
        r = self._rot
        fe = r[0] * fx + r[1] * fy + r[2] * fz
        fn = r[3] * fx + r[4] * fy + r[5] * fz
        # (|f| - g)^2 without the root: |f|^2 - g^2 = (|f| - g)(|f| + g) ~ 2 g (|f| - g)
        g = self._gravity
        da = (fx * fx + fy * fy + fz * fz - g * g) / (2.0 * g)
        self._still_a += k * (da * da + fe * fe + fn * fn - self._still_a)
        quiet = self._still_g < self._still_g2 and self._still_a < self._still_a2
        # A car pulling away smoothly looks quiet to an IMU: only the GNSS can say it stands.
        # (Never the filter's own speed alone: a zero-velocity update would hold itself.)
        if quiet and self.kf.initialized:
            v = self._still_v
            quiet = (self._gnss_speed_t is not None and self._gnss_speed < v
                     and self._t_imu - self._gnss_speed_t < self._gnss_timeout_ns
                     and math.hypot(self.kf.x[3], self.kf.x[4]) < v)
        if quiet:
            self._still_s += dt
            if self._still_s > 1.0 and self.aligned:
                # the car stands: what the gyro reads is its bias (gx.. are already corrected)
                kb = dt / 5.0
                b = self.gyro_bias
                b[0] += kb * gx; b[1] += kb * gy; b[2] += kb * gz
        else:
            self._still_s = 0.0

    @property
    def still(self) -> bool:
        return self._still_s > 1.0

    @property
    def heading_valid(self) -> bool:
        return self.heading.valid or self.mag_heading

    # -- pseudo-measurements -------------------------------------------------------------------
    def _pseudo_measurements(self):
        """What the car's nature says, as measurement rows (H, innovation, R) on the
        velocity, or None: a standing car stands (zero velocity); a moving one neither
        slides sideways nor leaves the road (non-holonomic: body x and z velocity zero)."""
        kf = self.kf
        ve, vn, vu = kf.x[3], kf.x[4], kf.x[5]
        if self.still:
            self.counts["zupt"] += 1
            return _ZUPT_H, [-ve, -vn, -vu], self._zupt_R
        if not (self._nhc and self.heading_valid and self.aligned):
            return None
        r = self._rot
        speed2 = ve * ve + vn * vn + vu * vu
        # an attitude error turns the constraint: widen it by speed x angle sigma
        sig2 = self._nhc_var
        R = np.array(((sig2 + speed2 * self._yaw_var(), 0.0), (0.0, sig2 + speed2 * self._tilt_var[1])))
        H = np.zeros((2, 9))
        H[0, 3:6] = r[0], r[3], r[6]                      # body x (right) in ENU
        H[1, 3:6] = r[2], r[5], r[8]                      # body z (up)
        self.counts["nhc"] += 1
        return H, [-(r[0] * ve + r[3] * vn + r[6] * vu), -(r[2] * ve + r[5] * vn + r[8] * vu)], R

    def _constraints(self) -> None:
        """The pseudo-measurements on their own, when no GNSS fix has carried them lately."""
        pseudo = self._pseudo_measurements()
        if pseudo is None:
            self.kf.flush()
            return
        _, _, dx = self.kf.update(*pseudo)
        self._history.correct(dx[0:3], dx[3:6])

    def _yaw_var(self) -> float:
        if self.heading.valid:
            return self.heading.yaw_var
        return math.radians(3.0) ** 2 if self.mag_heading else UNKNOWN_VAR

    # -- GNSS --------------------------------------------------------------------------------
    def _use_fix(self, fix: Fix) -> None:
        try:
            self._use_fix_unsafe(fix)
        except Diverged as exc:
            self._reset(f"diverged: {exc}")

    def _gnss_reject(self, reason: str) -> None:
        self.gnss_rejected[reason] = self.gnss_rejected.get(reason, 0) + 1

    def _use_fix_unsafe(self, fix: Fix) -> None:
        s = self.settings
        if not fix.usable:
            self._gnss_reject("status")
            return
        self._last_fix_t[fix.unit] = max(fix.t, self._last_fix_t.get(fix.unit, fix.t))
        # A receiver's errors are correlated over a second or more: fixes at 20 Hz are
        # not 20 independent measurements a second. Fewer cost less and lose nothing.
        used = self._used_fix_t.get(fix.unit)
        if used is not None and 0 <= fix.t - used < self._fix_interval_ns:
            self.counts["gnss_decimated"] += 1
            return
        self._used_fix_t[fix.unit] = fix.t
        if max(fix.ecef_sigma_m) > s["max_pos_sigma_m"]:
            self._gnss_reject("sigma")
            return
        if self.frame is None:
            self._set_origin(LocalFrame.at_ecef(fix.ecef_m), "first_fix")
        frame = self.frame
        imu_mode = self._imu_live(fix.t)
        if not imu_mode:
            self._coast_to(fix.t)

        z = frame.enu_of_ecef(fix.ecef_m)
        Rp = frame.cov_to_enu(fix.ecef_sigma_m)
        lever = self._levers.get(fix.unit, self._lever_default)
        r = self._rot
        known_att = self.aligned and self.heading_valid
        if known_att:
            arm = _rotate(r, lever)
        else:                                   # the arm's direction is unknown: widen the fix
            arm = (0.0, 0.0, 0.0)
            Rp = Rp + np.eye(3) * (lever[0] ** 2 + lever[1] ** 2 + lever[2] ** 2)
        vel = velR = None
        if fix.vel_ecef_mps is not None:
            vel = frame.vector_to_enu(fix.vel_ecef_mps)
            sig = fix.vel_sigma_mps or (s["vel_sigma_default_mps"],) * 3
            velR = frame.cov_to_enu(sig)
            # the antenna moves with the car's turning: v_ant = v + R (w x r)
            w = self._rate if imu_mode else (0.0, 0.0, 0.0)
            arm_v = _rotate(r, _cross(w, lever)) if known_att else (0.0, 0.0, 0.0)
            vel = (vel[0] - arm_v[0], vel[1] - arm_v[1], vel[2] - arm_v[2])

        kf = self.kf
        if not kf.initialized:
            self._initialize(fix, z, Rp, arm, vel, velR)
            return

        then = self._state_at(fix.t)
        if then is None:
            self._reject_input("gnss_late")
            return
        p = then[0]
        nu_p = [z[0] - p[0] - arm[0], z[1] - p[1] - arm[1], z[2] - p[2] - arm[2]]
        nu_v = None
        if vel is not None:
            then_v = self._state_at(fix.t - int(fix.vel_latency_s * 1e9) if self._vel_latency else fix.t)
            if then_v is not None:
                v, yaw = then_v[1], then_v[2]
                self._gnss_speed, self._gnss_speed_t = math.hypot(vel[0], vel[1]), fix.t
                nu_v = [vel[0] - v[0], vel[1] - v[1], vel[2] - v[2]]
        pseudo = self._pseudo_measurements() if imu_mode else None
        if pseudo is not None:
            self._last_pseudo_t = self._t_state
        pos_ok, vel_ok, dx = kf.update_fix(nu_p, Rp, nu_v, velR, pseudo, s["gate_chi2"])
        if dx is not None:
            self._history.correct(dx[0:3], dx[3:6])
        if pos_ok:
            self.gnss_used += 1
        else:
            self._gnss_reject("innovation")
        if vel is not None and not vel_ok:
            self._gnss_reject("velocity_innovation")
        if pos_ok and (vel_ok or vel is None):
            self._reject_since = None
        else:
            self._disagreement(fix, z, Rp, arm, vel, velR)
        if vel_ok:
            self._course(vel, velR, yaw)

    def _disagreement(self, fix, z, Rp, arm, vel, velR) -> None:
        """Usable fixes keep failing the innovation test: after gnss_reset_s, believe GNSS.

        A single wild fix is the receiver's fault; minutes of them are ours (a wrong
        velocity, a drift while coasting) or a jump the receiver really made.
        """
        if self._reject_since is None:
            self._reject_since = fix.t
            return
        limit = self.settings["gnss_reset_s"]
        if (fix.t - self._reject_since) * 1e-9 <= limit:
            return
        self.counts["resets"] += 1
        self.last_reset = f"GNSS disagreed for {limit:g} s: position and velocity reinitialised"
        self.log.warning("%s", self.last_reset)
        self.kf.reset()
        self._history.clear()
        self._reject_since = None
        self._initialize(fix, z, Rp, arm, vel, velR)

    def _initialize(self, fix, z, Rp, arm, vel, velR) -> None:
        """First usable fix: position (and velocity) straight from GNSS."""
        if vel is None:
            vel, velR = (0.0, 0.0, 0.0), np.eye(3) * 25.0       # unknown: a car is below 5 m/s
        dt = 0.0 if self._t_state is None else max(0.0, (self._t_state - fix.t) * 1e-9)
        pos = [z[k] - arm[k] + vel[k] * dt for k in range(3)]
        self.kf.initialize(pos, Rp, vel, velR)
        if self._t_state is None or self._t_state < fix.t:
            self._t_state = fix.t
        self._history.clear()
        self.gnss_used += 1
        self.log.info("position initialised from %s: ENU %.2f %.2f %.2f", fix.unit, *pos)
        self._course(vel, velR, math.atan2(self._rot[3], self._rot[0]))

    def _course(self, vel, velR, yaw_then) -> None:
        """Yaw from the direction of travel, when moving fast enough for it to mean something."""
        s = self.settings
        if not s["course_heading"]:
            return
        speed = math.hypot(vel[0], vel[1])
        if speed < s["course_min_speed_mps"]:
            return
        var = 0.5 * float(velR[0, 0] + velR[1, 1]) / (speed * speed)
        measured = course_yaw(vel[0], vel[1])
        h = self.heading
        if h.valid or self.mag_heading:
            e = wrap_angle(measured - yaw_then)
            if abs(e) > 0.5 * math.pi and self._yaw_var() < math.radians(30.0) ** 2:
                e = wrap_angle(e + math.pi)        # reversing: the car points against its course
            if not h.valid:
                h.set(self._yaw_var())
            corr = h.correct(e, var, self.settings["gate_chi2"])
            if corr is None:
                self._gnss_reject("course_innovation")
                return
        else:
            yaw_now = math.atan2(self._rot[3], self._rot[0])
            corr = wrap_angle(measured - yaw_then)
            h.set(var)
            self.log.info("yaw %.1f deg from the course over ground at %.1f m/s",
                          math.degrees(wrap_angle(yaw_now + corr)), speed)
        self.counts["course_used"] += 1
        # the heading filter's bias is what the gyro correction still misses: feed it back
        self.gyro_bias[2] += h.bias
        h.bias = 0.0
        self.att.rotate_world_z(corr)
        self._history.correct(dyaw=corr)
        self._rot = _rotation(self.att)
        if abs(corr) > 0.1:
            self._vb = None                  # a jump in yaw is not an acceleration

    def _imu_live(self, t: int) -> bool:
        return self._t_imu is not None and abs(t - self._t_imu) < self._imu_timeout_ns

    def _coast_to(self, t: int) -> None:
        """No IMU: move the state to the fix's time with the constant-velocity model."""
        if self._t_state is None or t <= self._t_state:
            self._t_state = t if self._t_state is None else self._t_state
            return
        dt = (t - self._t_state) * 1e-9
        if self.kf.initialized:
            self.kf.move(0.0, 0.0, 0.0, dt)
        if self.heading.valid:
            self.heading.coast(dt)
        self._t_state = t
        self._history.clear()

    def _state_at(self, t: int):
        """(p, v, yaw) at time t: now, or from the history for a late fix."""
        x = self.kf.x
        yaw_now = math.atan2(self._rot[3], self._rot[0])
        if self._t_state is None or t >= self._t_state:
            return x[0:3], x[3:6], yaw_now
        then = self._history.at(t)
        if then is not None:
            return then
        dt = (self._t_state - t) * 1e-9
        if dt <= self.settings["late_window_s"]:
            # older than the history: just after (re)initialisation. Extrapolate back.
            return [x[k] - x[3 + k] * dt for k in range(3)], x[3:6], yaw_now
        return None

    # -- bookkeeping ---------------------------------------------------------------------------
    def _check_future(self, t: int) -> None:
        if self._clock is not None:
            if t - self._clock() > self._future_ns:
                raise Rejected("future")
        elif self._t_state is not None and t - self._t_state > 3600 * 10**9:
            # offline there is no clock: an hour ahead of everything so far is a bad time,
            # unless it goes on (a recording made of two sessions)
            self._refused_in_a_row += 1
            if self._refused_in_a_row < _TIMELINE_RESTART:
                raise Rejected("future", "an hour ahead of the state")
            self._restart_timeline("times jumped ahead")

    def _restart_timeline(self, why: str) -> None:
        """Inputs keep disagreeing with the time so far: the time so far was the wrong one."""
        self._t_imu = self._t_state = None
        self._pending.clear()
        self._last_fix_t.clear()
        self._used_fix_t.clear()
        self._refused_in_a_row = 0
        self._reset(f"{why} for {_TIMELINE_RESTART} inputs in a row: a new timeline")

    def _reject_input(self, reason: str) -> None:
        self.input_rejected[reason] = self.input_rejected.get(reason, 0) + 1

    # -- output --------------------------------------------------------------------------------
    def state(self) -> dict:
        """The state as a viena.estimator.state/1 sample. Never carries a NaN: if the
        filter produced one, it resets and reports the reset state instead."""
        try:
            out, numbers = self._state()
            total = sum(numbers)
            reason = None if total - total == 0.0 else "a state value was not finite"
        except (Diverged, ValueError) as exc:
            reason = str(exc)
        if reason is not None:
            self._reset(f"diverged: {reason}")
            out, _ = self._state()
        return out

    def _state(self) -> tuple[dict, list]:
        """The sample, and its floats (a sum of them is finite if and only if they all are)."""
        self._seq += 1
        kf = self.kf
        if kf.initialized:
            x = kf.x
            d = kf.P.diagonal().tolist()      # as of the last update or covariance step
            pos, vel, bias, pos_var, vel_var = x[0:3], x[3:6], x[6:9], d[0:3], d[3:6]
        else:
            pos = vel = bias = [0.0, 0.0, 0.0]
            pos_var = vel_var = [NavKalman.MAX_POS_VAR] * 3
        w, qx, qy, qz = q = self.att.q
        yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * qy - qz * qx))))
        roll = math.atan2(2 * (w * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
        t = self._t_state or _time_floor()
        frame = self.frame
        geo = (None, None, None)
        if frame is not None and kf.initialized:
            geo = frame.geodetic_of_enu(pos[0], pos[1], pos[2])
        mag, course = self.mag_heading, self.heading.valid
        att_var = [self._yaw_var(), *(self._tilt_var if self.aligned else (UNKNOWN_VAR,) * 2)]
        out = {
            "t": t,
            "seq": self._seq,
            "mode": self._mode(),
            "aligned": self.aligned,
            "heading_valid": mag or course,
            "heading_source": ("mag+course" if mag and course else "mag" if mag else
                               "course" if course else "none"),
            "position_valid": kf.initialized,
            "imu_live": self.imu_live,
            "gnss_live": sorted(u for u, tf in self._last_fix_t.items() if t - tf < self._gnss_timeout_ns),
            "origin": list(frame.origin) if frame else None,
            "origin_source": self.origin_source,
            "enu_m": list(pos),
            "enu_var_m2": pos_var,
            "lat_deg": geo[0], "lon_deg": geo[1], "height_m": geo[2],
            "vel_enu_mps": list(vel),
            "vel_var_m2ps2": vel_var,
            "speed_mps": math.hypot(vel[0], vel[1]),
            "quat": list(q),
            "yaw_rad": yaw, "pitch_rad": pitch, "roll_rad": roll,
            "att_var_rad2": att_var,
            "rate_body_radps": list(self._rate),
            "accel_bias_mps2": list(bias),
            "gyro_bias_radps": list(self.gyro_bias),
            "gnss_used": self.gnss_used,
            "gnss_rejected": dict(self.gnss_rejected),
            "input_rejected": dict(self.input_rejected),
            "counts": dict(self.counts),
            "last_reset": self.last_reset,
            "waypoint": list(self.waypoint) if self.waypoint else None,
            "wp_bearing_deg": None, "wp_distance_m": None, "wp_heading_error_deg": None,
        }
        if self.waypoint and geo[0] is not None:
            out.update(waypoint_guidance(geo[0], geo[1], yaw, *self.waypoint, geo[2]))
        numbers = [*pos, *vel, *bias, *pos_var, *vel_var, *q, *att_var, *self._rate, *self.gyro_bias]
        if geo[0] is not None:
            numbers += geo
        return out, numbers

    def _mode(self) -> str:
        t = self._t_state
        if t is None:
            return "waiting"
        if not self.imu_live:
            return "gnss_only" if self.kf.initialized else "waiting"
        if not self.aligned:
            return "aligning"
        if not self.kf.initialized:
            return "attitude"
        gnss = any(t - tf < self._gnss_timeout_ns for tf in self._last_fix_t.values())
        return "navigating" if gnss else "coasting"


# -- small helpers (plain floats: these run per sample) ----------------------------------------
def _rotation(att: Madgwick) -> tuple:
    """Body -> ENU rotation matrix of the attitude, row-major 9-tuple."""
    w, x, y, z = att.q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def _rotate(r, v):
    return (r[0] * v[0] + r[1] * v[1] + r[2] * v[2],
            r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
            r[6] * v[0] + r[7] * v[1] + r[8] * v[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _time_floor() -> int:
    """A valid schema time for a state before any input (1980-01-06, the GPS epoch)."""
    return 315_964_800_000_000_000
