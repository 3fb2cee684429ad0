"""A GNSS fix into the filters: gates, lever arm, the state at the fix's time, resets.

For each fix the timeline hands over:
- gates: a solution (status), used at most `gnss_max_rate_hz` per receiver, sigmas below
  `max_pos_sigma_m`;
- the measurement: the antenna's ENU position and velocity with their covariances (from
  ENU sigmas when the fix has them, else from ECEF ones), the lever arm taken off
  (p + R l, v + R (w x l)); while the attitude is unknown the arm's direction is too,
  and its length widens the fix;
- the fix's variance, no less than its solution kind's floor (`gnss_sigma_floor_m`),
  split into a white part and the receiver's slowly wandering error (gnss_noise.py, the
  receiver's error states in kalman.py; a carrier-phase fix is white up to its floor),
  each fix widened by what the IMU clock's uncertainty makes of it (timing.py);
- a change of the receiver's solution kind (single, dgps, float, fixed and back) is a
  known step, not a fault: the receiver's error starts again at the new kind's size, so
  the step goes into it, not into the position; a step to a better kind is believed
  (the position widens to it if the gate would refuse it), when it is within 3 sigma of
  the old kind's fixes and at most once per receiver every STEP_BELIEVED_EVERY_S;
- the innovation against the state *at the fix's time* (the trajectory history), and
  the velocity's at its own, older time (its latency: `gnss_vel_latency_s`, else the
  fix's `vel_latency_s`); one Kalman update with the car's pseudo-measurements riding
  along, each block gated (docs/estimator.md#innovation-gate); the tilt it found goes to
  the attitude;
- the yaw: the course over ground from a velocity that passed, or, after a few refused
  in a row, from the refused one with its disagreement as its uncertainty; from the
  positions' own direction for a receiver without velocity (NMEA GGA);
- usable fixes that keep failing the gate for `gnss_reset_s`, or an IMU-driven velocity
  that no car's motion explains (IMU_CONTRADICTED_MPS off at two fixes in a row): GNSS is
  believed, position and velocity start again from it, yaw and tilt from scratch.
Equations: docs/estimator.md#gnss-update-and-lever-arm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from viena.common.geodesy import LocalFrame
from viena.common.samples.fix import Fix
from viena.services.estimator import fix_measurement, gnss_judgement
from viena.services.estimator.admission import Admission
from viena.services.estimator.gnss_course import Courses
from viena.services.estimator.gnss_gates import FixGates
from viena.services.estimator.gnss_judgement import IMU_CONTRADICTED_MPS, Disagreement, SolutionSteps
from viena.services.estimator.gnss_noise import WhiteShare
from viena.services.estimator.kalman_update import Diverged
from viena.services.estimator.timing import OffsetHint

if TYPE_CHECKING:                       # the estimator holds this part: types only, no cycle
    from viena.services.estimator.estimator import Estimator

#: a receiver's positions refused while its velocity agrees are its own doing for this long
#: (s: a multipath burst lasts up to half a minute) before the filter widens or resets
POSITION_ALONE_S = 30.0
#: ... when they are off by less than this (m): a jump of tens of metres is no multipath
POSITION_ALONE_MAX_M = 10.0
#: the mount hint learns only while the pitch is known better than this (rad^2: 1 deg)
MOUNT_TILT_VAR = math.radians(1.0) ** 2


@dataclass(frozen=True)
class _Measured:
    """A fix made a measurement: the antenna's position z (ENU) and covariance, its white
    part, the position's R, the arm, the body origin's velocity and its R, the receiver's
    wandering sigmas and white share, whether the IMU drove the state and the arm is known."""
    fix: Fix
    z: tuple
    cov: np.ndarray
    white_cov: np.ndarray
    Rp: np.ndarray
    arm: tuple
    vel: tuple[float, float, float] | None
    velR: np.ndarray | None
    wander: tuple[float, float, float]
    share: WhiteShare
    imu_mode: bool
    known_att: bool


class GnssUpdate:
    """The estimator's GNSS side: it reads `est`, the Estimator, and decides; what changes
    the filters it asks of the Estimator's `Navigation` half (navigation.py)."""

    def __init__(self, est: Estimator) -> None:
        self.est = est
        s = self.settings = est.settings
        self.lever_default, self.levers = gnss_judgement.lever_arms(s)
        self.gates = FixGates(s)                # status, rate, sigma; receivers alive (gnss_gates.py)
        self.white: dict[tuple[str, str], WhiteShare] = {}  # what is white of each receiver's
        #                                                    variance, per solution kind
        self.steps = SolutionSteps()            # each receiver's solution kind, its steps
        #: each receiver's last fix whose position the filter took: (t, kind, diff_age_s), for the state
        self.solutions: dict[str, tuple[int, str, float | None]] = {}
        self.floors = gnss_judgement.floors(s.gnss_sigma_floor_m)
        self.level: dict[str, tuple] = {}       # each receiver's variance, smoothed, and when
        self.timing = OffsetHint()              # what the residuals say of the IMU's clock
        self.admission = Admission(s)           # which receivers are in use (admission.py)
        self.restart()

    def restart(self) -> None:
        """A new estimate: forget what the old one made of the fixes (not their times)."""
        self.disagreement = Disagreement()      # refusals in a row, IMU contradictions
        self.speed: float = math.inf            # last GNSS horizontal speed, ...
        self.speed_t: int | None = None         # ... and its time
        self.courses = Courses(self.settings.gate_chi2)     # velocities refused in a row, recent positions
        self.steps.restart()
        self.arm_known = False                  # the position is the body origin's, not an antenna's
        self._forget_shares()

    def _forget_shares(self) -> None:
        for share in self.white.values():
            share.forget()

    def forget_times(self) -> None:
        """A new timeline: the receivers' times so far mean nothing."""
        self.gates.forget_times()
        self.steps.believed_t.clear()
        self.timing = OffsetHint()

    def time_var(self) -> float:
        """Variance of the IMU's clock against GNSS's (s^2): the setting's, and the offset
        the residuals point at, until it is set right."""
        late = self.timing.late_s
        return self.settings.imu_time_sigma_s ** 2 + late * late

    # -- one fix -------------------------------------------------------------------------------
    def use(self, fix: Fix) -> None:
        try:
            self._use(fix)
        except Diverged as exc:
            self.est.reset(f"diverged: {exc}")

    def _use(self, fix: Fix) -> None:
        est = self.est
        admitted = self._admit(fix)
        if admitted is None:
            return
        m = self._measure(fix, *admitted)
        if not est.kf.initialized:
            self._initialize(fix, m.z, m.Rp, m.arm, m.vel, m.velR, m.wander)
            return
        if m.known_att and not self.arm_known:
            # while the yaw was unknown the position followed the antenna; now that the
            # arm's direction is known, it moves to the body origin (and its past with it)
            est.to_body_origin(m.arm)
            self.arm_known = True
        self._update(m)

    def _admit(self, fix: Fix):
        """(z, cov, floor) of a fix the gates let through, else None (counted)."""
        est, counters = self.est, self.est.counters
        why = self.gates.refuse(fix)
        if why == "decimated":
            counters.counts["gnss_decimated"] += 1
        elif why is not None:
            counters.gnss(why)
        if why is not None:
            return None
        if est.frame is None:
            est.set_origin(LocalFrame.at_ecef(fix.ecef_m), "first_fix")
        assert est.frame is not None
        floor = self.floors.get(fix.kind)
        z, cov = fix_measurement.position(fix, est.frame, floor)
        why = self.admission.admit(fix, np.sqrt(cov.diagonal()), z, est.standstill.still)
        if why is not None:
            counters.gnss(why)
            return None
        return z, cov, floor

    def _measure(self, fix: Fix, z, cov, floor) -> _Measured:
        """The fix as a measurement: arm, velocity, its noise; the receiver's error block."""
        est, s, unit, kind = self.est, self.settings, fix.unit, fix.kind
        before = self.steps.changed(unit, kind)
        if before is not None:
            self._kind_changed(unit, before, kind)
        imu_mode = est.timeline.imu_live_at(fix.t)
        if not imu_mode and est.coast_to(fix.t):
            self._forget_shares()
        lever = self.levers.get(unit, self.lever_default)
        att = est.attitude
        pose = fix_measurement.Pose(att.rot, att.rate, att.aligned and est.heading.valid)
        assert est.frame is not None
        arm, vel, velR = fix_measurement.antenna(fix, est.frame, pose, lever, imu_mode, s.vel_sigma_default_mps)
        share = self.white.get((unit, kind))
        if share is None:
            share = self.white[unit, kind] = WhiteShare.of_kind(kind, s.gnss_white_fraction)
        fn = fix_measurement.noise(cov, floor, share, self.level.get(unit), fix.t)
        self.level[unit] = fn.level
        # without the IMU (or its yaw) nothing tells the car's motion from the fixes'
        # jumps: the constant-velocity model would follow every one; the whole sigma is the fix's
        driven = imu_mode and est.heading.valid
        Rp = fn.white_cov if driven else cov
        if not pose.known:                  # the arm's direction is unknown: widen the fix
            Rp = Rp + np.eye(3) * (lever[0] ** 2 + lever[1] ** 2 + lever[2] ** 2)
        if s.gnss_bias_tau_s > 0:
            est.receiver_block(unit, fn.wander, kind)
        else:
            Rp = cov + (Rp - fn.white_cov if driven else 0.0)
        return _Measured(fix, z, cov, fn.white_cov, Rp, arm, vel, velR, fn.wander, share,
                         imu_mode, pose.known)

    def _update(self, m: _Measured) -> None:
        """The innovations against the state at the fix's time, one update, its judgement."""
        est, s, fix = self.est, self.settings, m.fix
        unit, z, Rp, arm, vel, velR = fix.unit, m.z, m.Rp, m.arm, m.vel, m.velR
        imu_mode = m.imu_mode
        kf, att, counters, timeline = est.kf, est.attitude, est.counters, est.timeline
        var = m.cov.diagonal()
        share = m.share
        then = est.state_at(fix.t)
        if then is None:
            counters.input("gnss_late")
            return
        p, v_then = then[0], then[1]
        # a late fix: the antenna's arm (and the turn's acceleration) as the car pointed then
        c, sn = math.cos(then[2] - att.yaw), math.sin(then[2] - att.yaw)
        arm = (c * arm[0] - sn * arm[1], sn * arm[0] + c * arm[1], arm[2])
        accel = est.accel_enu
        accel = (c * accel[0] - sn * accel[1], sn * accel[0] + c * accel[1], accel[2])
        if imu_mode:
            # a wrong IMU clock puts the state v dt behind or ahead of the fix: widen by it
            dt2 = self.time_var()
            Rp = Rp + dt2 * np.outer(v_then, v_then)
            raw = est.history.raw_position(fix.t, kf.x, timeline.t_state)
            if raw is not None:
                share.observe(fix.t, z, (raw[0] + arm[0], raw[1] + arm[1], raw[2] + arm[2]),
                              var[0], var[1], var[2])
        g = kf.receiver_error(unit)
        nu_p = [z[0] - p[0] - arm[0] - g[0], z[1] - p[1] - arm[1] - g[1], z[2] - p[2] - arm[2] - g[2]]
        nu_v = None
        yaw = None
        course_var = 0.0
        if vel is not None:
            latency = s.gnss_vel_latency_s.get(unit, fix.vel_latency_s) if s.use_vel_latency else 0.0
            then_v = est.state_at(fix.t - int(latency * 1e9))
            if then_v is not None:
                v, yaw = then_v[1], then_v[2]
                self.speed, self.speed_t = math.hypot(vel[0], vel[1]), fix.t
                nu_v = [vel[0] - v[0], vel[1] - v[1], vel[2] - v[2]]
                if imu_mode:
                    assert velR is not None, "a velocity comes with its covariance"
                    self.timing.course(fix.t - int(latency * 1e9), vel[0], vel[1],
                                       float(velR[0, 0] + velR[1, 1]) * 0.5)
                    dt2 = self.time_var()
                    velR = velR + dt2 * np.outer(accel, accel)
                    course_var = dt2 * att.rate[2] ** 2
        pseudo = est.pseudo_rows() if imu_mode else None
        if unit in self.steps.stepped_up:
            self._widen_to_step(nu_p, Rp, fix, self.steps.stepped_up.pop(unit))
        result = est.update_by_fix(nu_p, Rp, nu_v, velR, pseudo, unit)
        self._judge(m, Rp, velR, nu_p, nu_v, result, yaw, course_var)

    def _judge(self, m: _Measured, Rp, velR, nu_p, nu_v, result, yaw, course_var: float) -> None:
        """What the update's result says: of the receiver, the filter, the IMU, the yaw."""
        est, s, fix, unit, z, arm, vel = self.est, self.settings, m.fix, m.fix.unit, m.z, m.arm, m.vel
        imu_mode, known_att, white_cov, wander = m.imu_mode, m.known_att, m.white_cov, m.wander
        counters, (pos_ok, vel_ok, d2p, d2v) = est.counters, result
        if pos_ok:                          # what the estimate rests on: positions it took
            self._rests_on(fix)
        judge = est.consistency
        judge.seen("position", d2p, 3, s.gate_chi2)
        # positions refused while the same receiver's velocity agrees: its position alone
        # is off (a multipath burst, a jump when its satellites change), not the filter
        alone = (nu_v is not None and vel_ok
                 and nu_p[0] * nu_p[0] + nu_p[1] * nu_p[1] < POSITION_ALONE_MAX_M ** 2)
        if judge.refused(unit, "position", pos_ok, fix.t, POSITION_ALONE_S if alone else None):
            est.inflate(0, nu_p)
            counters.counts["inflations"] += 1
        if nu_v is not None:
            judge.seen("velocity", d2v, 3, s.gate_chi2)
            if judge.refused(unit, "velocity", vel_ok, fix.t):
                est.inflate(3, nu_v)
                counters.counts["inflations"] += 1
        est.follow_consistency()
        if pos_ok:
            counters.gnss_used += 1
        else:
            counters.gnss("innovation")
        if nu_v is not None and not vel_ok:
            counters.gnss("velocity_innovation")
        if pos_ok and (vel_ok or nu_v is None):
            self.disagreement.agreed()
        if nu_v is not None and imu_mode and self.disagreement.imu_contradicted(nu_v, vel_ok):
            # no car's motion takes its velocity this far from GNSS's between two fixes:
            # the IMU's samples were wrong (in range, but not physical); what they taught
            # the filters and the clock's hint goes too
            self.timing = OffsetHint()
            self._start_again(f"the IMU's velocity left GNSS's by more than {IMU_CONTRADICTED_MPS:g} m/s "
                              "at two fixes in a row", fix, z, Rp, arm, vel, velR, wander)
            return
        if not (pos_ok and (vel_ok or nu_v is None)) and self._disagreement(
                fix, z, Rp, arm, vel, velR, wander, POSITION_ALONE_S if alone else 0.0):
            return
        if vel_ok and imu_mode and known_att and est.tilt_var()[1] < MOUNT_TILT_VAR:
            # only a velocity the filter agrees with, with the pitch known, says how the
            # IMU sits (not one from a spell of trouble or a fresh alignment, which would
            # teach the constraint a wrong axis)
            est.mount_seen(vel)
        self.courses.use(est, fix, z, arm, white_cov, vel, velR, nu_v, vel_ok, yaw, course_var, imu_mode)

    def _kind_changed(self, unit: str, before: str, kind: str) -> None:
        """A receiver's solution changed kind: its error is another one from now on (the
        Kalman filter's block for it starts again at the next update). What was learnt of
        the old one's size and of its recent positions no longer holds."""
        est = self.est
        est.counters.counts["gnss_kind_changes"] += 1
        self.steps.stepped(unit, before, kind, self.level.pop(unit, None))
        self.courses.positions.forget(unit)
        share = self.white.get((unit, kind))
        if share is not None:
            share.forget()                  # its last fix was before the other kind's spell
        est.log.info("%s: solution %s -> %s (a known step: the receiver's error starts again)",
                     unit, before, kind)

    def _widen_to_step(self, nu_p, Rp, fix, old_level: tuple | None) -> None:
        """The first fix of a better kind: if the gate would refuse it (the estimate was
        surer of itself than the old kind's fixes deserved) and the step is believed
        (SolutionSteps), the position's covariance grows by it, nu nu^T, so it is taken."""
        est, unit = self.est, fix.unit
        if est.position_nis(nu_p, Rp, unit) <= self.settings.gate_chi2 or old_level is None:
            return
        why = self.steps.believe(unit, nu_p, Rp, old_level, fix.t)
        if why is not None:
            est.log.info("%s: %s: left to the gate", unit, why)
            return
        est.inflate(0, nu_p)
        est.counters.counts["kind_steps_believed"] += 1
        est.log.info("%s: the step to a better solution (%.2f m) widens the position",
                     unit, math.sqrt(nu_p[0] ** 2 + nu_p[1] ** 2 + nu_p[2] ** 2))

    def _rests_on(self, fix) -> None:
        """The filter took this fix's position: the estimate rests on its solution."""
        self.solutions[fix.unit] = (fix.t, fix.kind, fix.diff_age_s)

    def _disagreement(self, fix, z, Rp, arm, vel, velR, wander, at_least_s: float = 0.0) -> bool:
        """Usable fixes keep failing the innovation test: after gnss_reset_s (or
        `at_least_s`, for positions alone), believe GNSS. True if it did (position, velocity
        and yaw start again from this fix).

        A single wild fix is the receiver's fault; seconds of them are ours (a wrong
        velocity, a drift while coasting, a yaw gone wrong) or a jump the receiver really made.
        """
        refused_s = self.disagreement.refused_for(fix.t, self.est.gnss_timeout_ns)
        limit = max(self.settings.gnss_reset_s, at_least_s)
        if refused_s <= limit:
            return False
        self._start_again(f"GNSS disagreed for {limit:g} s", fix, z, Rp, arm, vel, velR, wander)
        return True

    def _start_again(self, why: str, fix, z, Rp, arm, vel, velR, wander) -> None:
        """Believe GNSS (Navigation.start_again): what was made of the fixes goes too; the
        yaw is forgotten, and the arm's direction with it."""
        self.disagreement.clear()
        self.courses.vel_refused.clear()
        self._forget_shares()
        if any(arm):
            lever = self.levers.get(fix.unit, self.lever_default)
            Rp = Rp + np.eye(3) * (lever[0] ** 2 + lever[1] ** 2 + lever[2] ** 2)
            arm = (0.0, 0.0, 0.0)
        self.est.start_again(why, fix, z, Rp, arm, vel, velR, wander)
        self._initialized(fix, arm)

    def _initialize(self, fix, z, Rp, arm, vel, velR, wander) -> None:
        """First usable fix: position (and velocity) straight from GNSS."""
        self.est.initialize_from(fix, z, Rp, arm, vel, velR, wander)
        self._initialized(fix, arm)

    def _initialized(self, fix, arm) -> None:
        self.arm_known = any(arm) or not any(self.levers.get(fix.unit, self.lever_default))
        self._rests_on(fix)
