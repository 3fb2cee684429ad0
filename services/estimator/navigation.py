"""The Estimator's filters, stepped by each IMU sample and corrected by what its parts return.

`Navigation` is the half of `Estimator` (estimator.py) that changes the filters: the
attitude, the Kalman filter and the trajectory history move with each IMU sample here,
and the corrections the GNSS side decides (gnss_update.py) and the constraints' rows are
applied here; no other part updates the Kalman filter. The heading and standstill parts
move the attitude through their own methods (the yaw once the heading is learnt, the
gyro's bias while the car stands).
"""
from __future__ import annotations

import logging
import math

import numpy as np

from viena.services.estimator.angles import tilt_about_car
from viena.services.estimator.attitude import Attitude
from viena.services.estimator.consistency import Consistency
from viena.services.estimator.constraints import Constraints
from viena.services.estimator.counters import Counters
from viena.services.estimator.gnss_update import GnssUpdate
from viena.services.estimator.heading import Heading
from viena.services.estimator.history import TrajectoryHistory
from viena.services.estimator.kalman import NavKalman
from viena.services.estimator.kalman_update import inverse_small, quadratic
from viena.services.estimator.mount import MountHint
from viena.services.estimator.settings import EstimatorSettings
from viena.services.estimator.standstill import Standstill
from viena.services.estimator.timeline import Timeline

#: a step between IMU samples longer than this and the attitude aligns again
_REALIGN_GAP_S = 2.0
#: an alignment knows the car's speed when a GNSS velocity came this recently (ns): within a
#: second, or a 1 Hz receiver's never would be, a fix always being up to 1 s old
_ALIGN_SPEED_AGE_NS = 1_500_000_000
#: a first fix without velocity: the car may be driving at anything up to 40 m/s (its sigma)
VEL_UNKNOWN_VAR = 40.0 ** 2


class Navigation:
    """The filters and how they move; made and restarted by `Estimator`."""

    settings: EstimatorSettings
    log: logging.Logger
    counters: Counters
    timeline: Timeline
    attitude: Attitude
    heading: Heading
    kf: NavKalman
    standstill: Standstill
    constraints: Constraints
    history: TrajectoryHistory
    gnss: GnssUpdate
    consistency: Consistency
    mount: MountHint
    gnss_timeout_ns: int
    accel_enu: tuple[float, float, float]
    _imu_gap_s: float
    _still_mps: float
    _gravity: float
    _mag: tuple | None

    def corrected(self, dx) -> None:
        """The Kalman filter corrected its state by dx: the past trajectory moves with it,
        and the tilt it found goes to the attitude."""
        self.history.correct(dx[0:3], dx[3:6])
        self.attitude.correct_tilt(*self.kf.take_tilt())

    def to_body_origin(self, arm) -> None:
        """The position followed the antenna while the yaw was unknown; the arm's direction
        known, it moves to the body origin (and its past with it)."""
        x = self.kf.x
        x[0] -= arm[0]
        x[1] -= arm[1]
        x[2] -= arm[2]
        self.history.correct(dp=(-arm[0], -arm[1], -arm[2]))

    def receiver_block(self, unit: str, wander, kind: str) -> None:
        """The Kalman filter's block for `unit`'s wandering error, of sigmas `wander`;
        another kind of solution, another error: the step goes into it."""
        kf = self.kf
        if kf.receiver_group(unit) not in (None, kind):
            kf.reset_receiver(unit, wander, kind)
        kf.receiver(unit, wander, kind)
        kf.rescale_receiver(unit, wander)

    def state_at(self, t: int):
        """(p, v, yaw) at time t: now, or from the history for a late fix; None if older
        than the history and the late window."""
        x = self.kf.x
        yaw_now = self.attitude.yaw
        t_state = self.timeline.t_state
        if t_state is None or t >= t_state:
            return x[0:3], x[3:6], yaw_now
        then = self.history.at(t)
        if then is not None:
            return then
        dt = (t_state - t) * 1e-9
        if dt <= self.settings.late_window_s:
            # older than the history: just after (re)initialisation. Extrapolate back.
            return [x[k] - x[3 + k] * dt for k in range(3)], x[3:6], yaw_now
        return None

    def coast_to(self, t: int) -> bool:
        """No IMU: move the state to a fix's time with the constant-velocity model. True if
        it moved (the history no longer holds)."""
        dt = self.timeline.coast_to(t)
        if dt <= 0.0:
            return False
        if self.kf.initialized:
            self.kf.move(0.0, 0.0, 0.0, dt)
        if self.heading.filter.valid:
            self.heading.filter.coast(dt)
        self.history.clear()
        return True

    def pseudo_rows(self):
        """The car's pseudo-measurements, to ride along with a fix's update (so they are
        not due on their own for a while), or None."""
        rows = self.constraints.rows(self.kf, self.attitude, self.heading, self.standstill.still,
                                     self.tilt_var()[1])
        if rows is not None:
            self.constraints.last_t = self.timeline.t_state
        return rows

    def position_nis(self, nu_p, Rp, unit: str) -> float:
        """The gate's statistic a fix's position innovation would have, as of now."""
        return quadratic(inverse_small(self.kf.position_innovation_cov(Rp, unit)), nu_p)

    def update_by_fix(self, nu_p, Rp, nu_v, velR, rows, unit: str):
        """One gated update by a fix of `unit` (position and/or velocity, pseudo-measurement
        `rows` riding along): (pos_ok, vel_ok, d2_pos, d2_vel); the correction is applied."""
        pos_ok, vel_ok, dx, d2p, d2v = self.kf.update_fix(nu_p, Rp, nu_v, velR, rows, self.settings.gate_chi2, unit)
        if dx is not None:
            self.corrected(dx)
        return pos_ok, vel_ok, d2p, d2v

    def inflate(self, first: int, nu) -> None:
        """A block refused again and again: its covariance grows by the disagreement."""
        self.kf.inflate(first, nu)

    def follow_consistency(self) -> None:
        """The process noise scaled as the filter's consistency says (consistency.py)."""
        self.kf.q_scale = self.consistency.q_scale

    def course(self, vel, vel_cov, yaw_then: float, extra_var: float = 0.0) -> None:
        """A course over ground for the heading filter, compared with the yaw then."""
        self.heading.course(vel, vel_cov, yaw_then, self.history, extra_var)

    def mount_seen(self, vel) -> None:
        """A velocity the filter agreed with, the pitch known: how the IMU sits."""
        att = self.attitude
        self.mount.observe(att.rot, vel, att.rate[2], "mag" not in self.heading.source)

    def initialize_from(self, fix, z, Rp, arm, vel, velR, wander) -> None:
        """Position (and velocity) straight from a fix, antenna position z and covariance
        Rp less the arm; the receiver's wandering error (sigmas `wander`) is in the
        position's error."""
        if vel is None:
            vel, velR = (0.0, 0.0, 0.0), np.eye(3) * VEL_UNKNOWN_VAR       # unknown: a car, below 40 m/s
        t_state = self.timeline.t_state
        dt = 0.0 if t_state is None else max(0.0, (t_state - fix.t) * 1e-9)
        pos = [z[k] - arm[k] + vel[k] * dt for k in range(3)]
        kf = self.kf
        kf.reset()
        if self.settings.gnss_bias_tau_s > 0:
            kf.receiver(fix.unit, wander, fix.kind)
        kf.initialize(pos, Rp, vel, velR, fix.unit)
        if self.attitude.aligned:
            kf.retilt(self.tilt_sigma_rad())
        self.timeline.catch_up(fix.t)
        self.history.clear()
        self.counters.gnss_used += 1
        self.log.info("position initialised from %s: ENU %.2f %.2f %.2f", fix.unit, *pos)
        self.course(vel, velR, self.attitude.yaw)

    def start_again(self, why: str, fix, z, Rp, arm, vel, velR, wander) -> None:
        """Believe GNSS: position and velocity start again from this fix, the yaw from the
        next course, roll and pitch from a new alignment (the attitude that made the
        velocity go wrong may have gone wrong itself)."""
        why = f"{why}: position, velocity and attitude reinitialised"
        self.counters.reset(why)
        self.log.warning("%s", why)
        self.kf.reset()
        self.history.clear()
        self.heading.forget()
        self.attitude.realign()
        self.initialize_from(fix, z, Rp, arm, vel, velR, wander)

    def tilt_sigma_rad(self) -> float:
        """How well a fresh alignment knows roll and pitch: the setting, or what the car's
        unknown acceleration made of it (attitude.py)."""
        return max(math.radians(self.settings.tilt_sigma_deg), math.sqrt(max(self.attitude.tilt_var)))

    def tilt_var(self) -> list[float]:
        """Variance of the tilt about the car's forward and right axes (rad^2): the Kalman
        filter's once it has a position, else the accelerometer's disagreement."""
        att = self.attitude
        if not (self.kf.initialized and att.aligned):
            return att.tilt_var
        return tilt_about_car(self.kf.P, att.rot)

    # -- one IMU sample ----------------------------------------------------------------------
    def _imu_step(self, t, dt, ax, ay, az, gx, gy, gz, mag) -> None:
        att = self.attitude
        if dt > self._imu_gap_s:
            self.counters.counts["imu_gaps"] += 1
            if dt > _REALIGN_GAP_S:
                att.realign()
            dt = 0.0
        # the state's clock: after a GNSS-only spell it may be ahead of the IMU
        dt_state = self.timeline.step_state(t)
        b = att.gyro_bias
        gx, gy, gz = gx - b[0], gy - b[1], gz - b[2]
        att.rate = (gx, gy, gz)
        self.gnss.timing.gyro(t, gz, dt)
        kf = self.kf
        kx = kf.x
        fx, fy, fz = ax - kx[6], ay - kx[7], az - kx[8]
        speed_still = None
        if kf.initialized:
            # GNSS (lately) and the filter both put the speed below still_speed_mps
            g, v = self.gnss, self._still_mps
            speed_still = (g.speed_t is not None and g.speed < v and t - g.speed_t < self.gnss_timeout_ns
                           and kx[3] * kx[3] + kx[4] * kx[4] < v * v)
        self.standstill.update(dt, gx, gy, gz, fx, fy, fz, att.rot, self._gravity, speed_still, att,
                               self.gnss.gates.doppler.span(t))
        if mag is not None:
            self._mag = mag
        if not att.aligned:
            self._aligning(t, dt_state, fx, fy, fz, gx, gy, gz, mag)
        else:
            self._navigate(t, dt, dt_state, fx, fy, fz, gx, gy, gz, mag)

    def _aligning(self, t, dt_state, fx, fy, fz, gx, gy, gz, mag) -> None:
        """An IMU sample while the attitude aligns: the filter coasts."""
        att, kf = self.attitude, self.kf
        kx = kf.x
        speed, known = 0.0, False
        if kf.initialized:
            speed = math.hypot(kx[3], kx[4])
            # a GNSS velocity came within the last fix or so (the filter's own variance
            # grows fast while nothing drives it during an alignment)
            speed_t = self.gnss.speed_t
            known = speed_t is not None and 0 <= t - speed_t < _ALIGN_SPEED_AGE_NS
        att.gather(t, fx, fy, fz, gx, gy, gz, mag, self.heading.filter.valid, speed, known,
                   self.standstill.gnss_moving)
        if kf.initialized:
            if dt_state > 0.0:
                kf.move(0.0, 0.0, 0.0, dt_state)
            if att.aligned:             # a new attitude: the filter's tilt starts again
                kf.retilt(self.tilt_sigma_rad())
            self.history.append(t, kf.x, att.yaw)

    def _navigate(self, t, dt, dt_state, fx, fy, fz, gx, gy, gz, mag) -> None:
        """An IMU sample with the attitude aligned: Madgwick, the filter's prediction, and
        the constraints when due."""
        att, kf, heading, standstill = self.attitude, self.kf, self.heading, self.standstill
        kx = kf.x
        r = att.rot
        forward_mps: float | None = None
        if kf.initialized and heading.valid:
            forward_mps = r[1] * kx[3] + r[4] * kx[4] + r[7] * kx[5]     # along the car's forward axis
        speed_t = self.gnss.speed_t
        aided = speed_t is not None and t - speed_t < 1_000_000_000
        att.update(dt, fx, fy, fz, gx, gy, gz, mag, forward_mps, aided, standstill.still)
        if dt > 0.0:
            heading.filter.pending_s += dt
        if not kf.initialized:
            return
        r = att.rot
        if dt_state > self._imu_gap_s:
            kf.move(0.0, 0.0, 0.0, dt_state)
        elif heading.valid:
            ae = r[0] * fx + r[1] * fy + r[2] * fz
            an = r[3] * fx + r[4] * fy + r[5] * fz
            au = r[6] * fx + r[7] * fy + r[8] * fz - self._gravity
            self.accel_enu = (ae, an, au)
            kf.move(ae, an, au, dt_state, r)
        else:
            # yaw unknown: the horizontal acceleration cannot be put in ENU; let GNSS lead
            au = r[6] * fx + r[7] * fy + r[8] * fz - self._gravity
            kf.move(0.0, 0.0, au, dt_state, r, vertical=True)
        if t >= self.constraints.next_t:
            self._constraints_due(t, aided, fx, fy, fz)
        self.history.append(t, kf.x, att.yaw)

    def _constraints_due(self, t, aided: bool, fx, fy, fz) -> None:
        """Every constraint interval: the tilt's residual, the magnetometer, the constraints."""
        att, c = self.attitude, self.constraints
        c.next_t = t + c.interval_ns
        att.tilt_residual(c.interval_ns * 1e-9)
        if aided and att.beta_aided == 0.0 and self._mag is not None and att.use_mag \
                and att.mag_plausible(self._mag, fx, fy, fz):
            self.heading.magnetometer(self._mag, self.history)
        if t - c.last_t >= c.interval_ns:          # no fix carried them lately: on their own
            rows = c.rows(self.kf, att, self.heading, self.standstill.still, self.tilt_var()[1])
            if rows is None:
                self.kf.flush()
            else:
                self.corrected(self.kf.update(*rows)[2])
