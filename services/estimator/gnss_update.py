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

import numpy as np

from viena.common.geodesy import LocalFrame
from viena.services.estimator.admission import Admission
from viena.services.estimator.attitude import cross, rotate
from viena.services.estimator.doppler import DopplerSpeeds
from viena.services.estimator.gnss_noise import WhiteShare, carrier_share
from viena.services.estimator.kalman import Diverged, inverse_small, quadratic
from viena.services.estimator.timing import OffsetHint
from viena.services.gnss.model.fix import SOLUTION_KINDS, Fix, solution_rank

#: the IMU-driven velocity this far (m/s) off GNSS's at this many fixes in a row: the IMU
#: is wrong (150 m/s^2 for a second is in the sensor's range, but no car's motion)
IMU_CONTRADICTED_MPS = 10.0
IMU_CONTRADICTED_FIXES = 2
#: a receiver's velocity refused this many times in a row: its course is used anyway
COURSE_AFTER_REFUSALS = 3
#: a position-only receiver's course is the line through at least this long of its fixes,
#: and at least POSITION_COURSE_FIXES of them (s) ...
POSITION_COURSE_S = 1.0
POSITION_COURSE_FIXES = 3
#: ... over at most this long (longer: a gap; the trajectory history keeps this much)
POSITION_COURSE_MAX_S = 2.5
#: ... used when its speed is this many times its own noise
CHORD_SIGMAS = 3.0
#: the largest white share: a receiver is never taken as having no wandering error at all
MAX_WHITE_SHARE = 0.98
#: a receiver's positions refused while its velocity agrees are its own doing for this long
#: (s: a multipath burst lasts up to half a minute) before the filter widens or resets
POSITION_ALONE_S = 30.0
#: ... when they are off by less than this (m): a jump of tens of metres is no multipath
POSITION_ALONE_MAX_M = 10.0
#: the mount hint learns only while the pitch is known better than this (rad^2: 1 deg)
MOUNT_TILT_VAR = math.radians(1.0) ** 2
#: a first fix without velocity: the car may be driving at anything up to 40 m/s (its sigma)
VEL_UNKNOWN_VAR = 40.0 ** 2
#: the size of a receiver's wandering error follows its sigmas over this long (s)
LEVEL_TAU_S = 30.0
#: the least wandering error's sigma (m): a fixed RTK solution has none, but the Kalman
#: filter's receiver block must keep a size (it is rescaled by ratios)
MIN_WANDER_M = 0.001
#: a step to a better kind is believed past the gate at most this often per receiver (s):
#: a float <-> fixed flicker (or a wrong integer fix, again and again) gets no more
STEP_BELIEVED_EVERY_S = 10.0
#: ... and only when it is within this many of the old kind's sigmas (and the new fix's)
STEP_BELIEVED_SIGMAS = 3.0


class GnssUpdate:
    """The estimator's GNSS side; `est` is the Estimator, whose current filters it corrects."""

    def __init__(self, est) -> None:
        self.est = est
        s = self.settings = est.settings
        self.lever_default = tuple(float(v) for v in s.default_lever_arm_m)
        self.levers = {u: tuple(float(v) for v in arm) for u, arm in s.gnss_lever_arm_m.items()}
        for arm in (self.lever_default, *self.levers.values()):
            if len(arm) != 3:
                raise ValueError("a lever arm is [x right, y forward, z up] in m")
        for unit, latency in s.gnss_vel_latency_s.items():
            if not 0.0 <= latency <= 1.0:
                raise ValueError(f"gnss_vel_latency_s.{unit}: a latency of 0 to 1 s, got {latency!r}")
        rate = s.gnss_max_rate_hz
        # a fix due at the rate is used even if it comes a little early (5 ms of jitter)
        self.fix_interval_ns = int(1e9 / rate) - 5_000_000 if rate > 0 else 0
        self.last_fix_t: dict[str, int] = {}    # last usable fix per unit
        self.used_fix_t: dict[str, int] = {}    # last fix used per unit (rate limit)
        self.white: dict[tuple[str, str], WhiteShare] = {}  # what is white of each receiver's
        #                                                    variance, per solution kind
        self.kind: dict[str, str] = {}          # each receiver's solution kind, last fix used
        #: each receiver's last fix whose position the filter took: (t, kind, diff_age_s), for the state
        self.solutions: dict[str, tuple[int, str, float | None]] = {}
        self.floors = _floors(s.gnss_sigma_floor_m)
        self.level: dict[str, tuple] = {}       # each receiver's variance, smoothed, and when
        self.step_believed_t: dict[str, int] = {}  # when each receiver's last step was believed
        self.timing = OffsetHint()              # what the residuals say of the IMU's clock
        self.admission = Admission(s)           # which receivers are in use (admission.py)
        self.doppler = DopplerSpeeds(s.admit_max_speed_sigma_mps)  # every receiver's speed, used or not
        self.restart()

    def restart(self) -> None:
        """A new estimate: forget what the old one made of the fixes (not their times)."""
        self.reject_since: int | None = None    # usable fixes failing the gate since
        self.last_refused_t = 0                 # ... the last of them
        self.contradicted = 0                   # fixes in a row whose velocity the IMU's left far
        self.speed: float = math.inf            # last GNSS horizontal speed, ...
        self.speed_t: int | None = None         # ... and its time
        self.vel_refused: dict[str, int] = {}   # each receiver's velocities refused in a row
        self.positions: dict[str, list] = {}    # a position-only receiver's recent positions
        #: receivers whose next fix steps to a better kind: the old kind's level (variances E, N, U)
        self.stepped_up: dict[str, tuple | None] = {}
        self.arm_known = False                  # the position is the body origin's, not an antenna's
        for share in self.white.values():
            share.forget()

    def forget_times(self) -> None:
        """A new timeline: the receivers' times so far mean nothing."""
        self.last_fix_t.clear()
        self.used_fix_t.clear()
        self.step_believed_t.clear()
        self.doppler.forget()
        self.timing = OffsetHint()

    def live_units(self, t: int, timeout_ns: int) -> list[str]:
        return sorted(u for u, tf in self.last_fix_t.items() if t - tf < timeout_ns)

    def solution(self, t: int, timeout_ns: int) -> tuple[str, float | None, dict[str, str]]:
        """What the estimate rests on at time t: the best solution kind among the receivers
        whose fixes went into the filter within `timeout_ns` ("none" if none did), the age of
        that kind's corrections now (the youngest, when they carry one and the kind has any),
        and each such receiver's kind."""
        live = {u: v for u, v in self.solutions.items() if t - v[0] < timeout_ns}
        kinds = {u: v[1] for u, v in sorted(live.items())}
        if not live:
            return "none", None, kinds
        best = max(kinds.values(), key=solution_rank)
        ages = [age + max(0.0, (t - tf) * 1e-9) for tf, kind, age in live.values()
                if kind == best and age is not None]
        age = min(ages) if ages and solution_rank(best) > solution_rank("single") else None
        return best, age, kinds

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
        est, s = self.est, self.settings
        counters = est.counters
        if not fix.usable:
            counters.gnss("status")
            return
        unit = fix.unit
        self.last_fix_t[unit] = max(fix.t, self.last_fix_t.get(unit, fix.t))
        self.doppler.add(fix)
        # A receiver's errors are correlated over a second or more: fixes at 20 Hz are
        # not 20 independent measurements a second. Fewer cost less and lose nothing.
        used = self.used_fix_t.get(unit)
        if used is not None and 0 <= fix.t - used < self.fix_interval_ns:
            counters.counts["gnss_decimated"] += 1
            return
        self.used_fix_t[unit] = fix.t
        sigma = fix.enu_sigma_m or fix.ecef_sigma_m
        assert sigma is not None, "read_fix refuses a fix with neither ECEF nor ENU sigmas"
        if max(sigma) > s.max_pos_sigma_m:
            counters.gnss("sigma")
            return
        if est.frame is None:
            est.set_origin(LocalFrame.at_ecef(fix.ecef_m), "first_fix")
        frame = est.frame
        z = frame.enu_of_ecef(fix.ecef_m)
        if fix.enu_sigma_m is not None:
            cov = np.diag(np.square(fix.enu_sigma_m))
        else:
            cov = frame.cov_to_enu(fix.ecef_sigma_m)
        kind = fix.kind
        floor = self.floors.get(kind)
        if floor is not None:               # no receiver is surer than its kind allows
            cov = cov + np.diag(np.maximum(0.0, np.square(floor) - cov.diagonal()))
        sig = np.sqrt(cov.diagonal())
        why = self.admission.admit(fix, sig, z, est.standstill.still)
        if why is not None:
            counters.gnss(why)
            return
        before = self.kind.get(unit)
        if before != kind:
            self.kind[unit] = kind
            if before is not None:
                self._kind_changed(unit, before, kind)
        timeline = est.timeline
        imu_mode = timeline.imu_live_at(fix.t)
        if not imu_mode:
            self._coast_to(fix.t)

        lever = self.levers.get(unit, self.lever_default)
        att = est.attitude
        r = att.rot
        known_att = att.aligned and est.heading.valid
        arm = rotate(r, lever) if known_att else (0.0, 0.0, 0.0)
        vel: tuple[float, float, float] | None = None
        velR: np.ndarray | None = None
        if fix.vel_ecef_mps is not None:
            vel = frame.vector_to_enu(fix.vel_ecef_mps)
            sig = fix.vel_sigma_mps or (s.vel_sigma_default_mps,) * 3
            velR = frame.cov_to_enu(sig)
            # the antenna moves with the car's turning: v_ant = v + R (w x r)
            w = att.rate if imu_mode else (0.0, 0.0, 0.0)
            arm_v = rotate(r, cross(w, lever)) if known_att else (0.0, 0.0, 0.0)
            vel = (vel[0] - arm_v[0], vel[1] - arm_v[1], vel[2] - arm_v[2])

        # the fix's variance: a white part, and the receiver's wandering error
        share = self.white.get((unit, kind))
        if share is None:
            share = self.white[unit, kind] = WhiteShare.of_kind(kind, s.gnss_white_fraction)
        if share.learns:
            sh, sv = min(MAX_WHITE_SHARE, share.horizontal), min(MAX_WHITE_SHARE, share.vertical)
        else:                               # carrier phase: white up to its kind's floor
            sh = carrier_share(0.5 * float(cov[0, 0] + cov[1, 1]), None if floor is None else floor[0])
            sv = carrier_share(float(cov[2, 2]), None if floor is None else floor[2])
        d = np.array([math.sqrt(sh), math.sqrt(sh), math.sqrt(sv)])
        white_cov = cov * np.outer(d, d)
        if imu_mode and est.heading.valid:
            Rp = white_cov
        else:
            # without the IMU (or its yaw) nothing tells the car's motion from the fixes'
            # jumps: the constant-velocity model would follow every one; the whole sigma
            # is the fix's
            Rp = cov
        var = cov.diagonal()
        # the wandering error's size follows the receiver's sigmas over LEVEL_TAU_S, not
        # each fix's: one fix with a wild sigma says little about the sky's error. A
        # carrier-phase receiver's growing sigma is its corrections ageing (an RTK solution
        # extrapolates them: centimetres a second): that size counts at once
        smoothed = self.level.get(unit)
        level: list[float]
        if smoothed is None:
            level = var.tolist()
        else:
            k = min(1.0, max(0.0, (fix.t - smoothed[3]) * 1e-9) / LEVEL_TAU_S)
            level = [smoothed[i] + k * (var[i] - smoothed[i]) for i in range(3)]
            if not share.learns:
                level = [max(level[i], var[i]) for i in range(3)]
        self.level[unit] = (*level[:3], fix.t)
        if share.learns:
            wander_var = ((1.0 - sh) * level[0], (1.0 - sh) * level[1], (1.0 - sv) * level[2])
        elif floor is not None:             # what a carrier-phase receiver says beyond its noise
            wander_var = (level[0] - floor[0] * floor[0], level[1] - floor[1] * floor[1],
                          level[2] - floor[2] * floor[2])
        else:
            wander_var = (0.0, 0.0, 0.0)
        wander = tuple(max(MIN_WANDER_M, math.sqrt(max(0.0, v))) for v in wander_var)
        if not known_att:                   # the arm's direction is unknown: widen the fix
            Rp = Rp + np.eye(3) * (lever[0] ** 2 + lever[1] ** 2 + lever[2] ** 2)

        kf = est.kf
        if s.gnss_bias_tau_s > 0:
            if kf.receiver_group(unit) not in (None, kind):
                # another kind of solution, another error: the step goes into it
                kf.reset_receiver(unit, wander, kind)
            kf.receiver(unit, wander, kind)
            kf.rescale_receiver(unit, wander)
        else:
            Rp = cov + (Rp - white_cov if imu_mode and est.heading.valid else 0.0)
        if not kf.initialized:
            self._initialize(fix, z, Rp, arm, vel, velR, wander)
            return
        if known_att and not self.arm_known:
            # while the yaw was unknown the position followed the antenna; now that the
            # arm's direction is known, it moves to the body origin (and its past with it)
            kf.x[0] -= arm[0]
            kf.x[1] -= arm[1]
            kf.x[2] -= arm[2]
            est.history.correct(dp=(-arm[0], -arm[1], -arm[2]))
            self.arm_known = True

        then = self._state_at(fix.t)
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
            then_v = self._state_at(fix.t - int(latency * 1e9))
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
        pseudo = None
        if imu_mode:
            pseudo = est.constraints.rows(kf, att, est.heading, est.standstill.still, est.tilt_var()[1])
        if pseudo is not None:
            est.constraints.last_t = timeline.t_state
        if unit in self.stepped_up:
            self._widen_to_step(nu_p, Rp, fix, self.stepped_up.pop(unit))
        pos_ok, vel_ok, dx, d2p, d2v = kf.update_fix(nu_p, Rp, nu_v, velR, pseudo, s.gate_chi2, unit)
        if dx is not None:
            est.corrected(dx)
        if pos_ok:                          # what the estimate rests on: positions it took
            self._rests_on(fix)
        judge = est.consistency
        judge.seen("position", d2p, 3, s.gate_chi2)
        # positions refused while the same receiver's velocity agrees: its position alone
        # is off (a multipath burst, a jump when its satellites change), not the filter
        alone = (nu_v is not None and vel_ok
                 and nu_p[0] * nu_p[0] + nu_p[1] * nu_p[1] < POSITION_ALONE_MAX_M ** 2)
        if judge.refused(unit, "position", pos_ok, fix.t, POSITION_ALONE_S if alone else None):
            kf.inflate(0, nu_p)
            counters.counts["inflations"] += 1
        if nu_v is not None:
            judge.seen("velocity", d2v, 3, s.gate_chi2)
            if judge.refused(unit, "velocity", vel_ok, fix.t):
                kf.inflate(3, nu_v)
                counters.counts["inflations"] += 1
        kf.q_scale = judge.q_scale
        if pos_ok:
            counters.gnss_used += 1
        else:
            counters.gnss("innovation")
        if nu_v is not None and not vel_ok:
            counters.gnss("velocity_innovation")
        if pos_ok and (vel_ok or nu_v is None):
            self.reject_since = None
        if nu_v is not None and imu_mode and self._imu_contradicted(nu_v, vel_ok):
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
        if vel_ok:
            self.vel_refused[unit] = 0
            if imu_mode and known_att and est.tilt_var()[1] < MOUNT_TILT_VAR:
                # only a velocity the filter agrees with, with the pitch known, says how the
                # IMU sits (not one from a spell of trouble or a fresh alignment, which would
                # teach the constraint a wrong axis)
                est.mount.observe(att.rot, vel, att.rate[2], "mag" not in est.heading.source)
            est.heading.course(vel, velR, yaw, est.history, course_var)
        elif nu_v is not None:
            # a velocity refused again and again may be right and the yaw wrong: let the
            # heading filter judge its course, as uncertain as the disagreement is large
            n = self.vel_refused[unit] = self.vel_refused.get(unit, 0) + 1
            assert vel is not None, "an innovation nu_v comes from a velocity"
            speed2 = vel[0] * vel[0] + vel[1] * vel[1]
            if n >= COURSE_AFTER_REFUSALS and speed2 > 0.0:
                course_var += (nu_v[0] * nu_v[0] + nu_v[1] * nu_v[1]) / speed2
                est.heading.course(vel, velR, yaw, est.history, course_var)
        elif vel is None:
            self._course_from_positions(fix, z, arm, white_cov, course_var, imu_mode)

    def _kind_changed(self, unit: str, before: str, kind: str) -> None:
        """A receiver's solution changed kind (corrections came, converged, stopped): its
        error is another one from now on. What was learnt of the old one's size and of its
        recent positions no longer holds; the Kalman filter's block for it starts again at
        the next update (`NavKalman.reset_receiver`), and a better kind is believed."""
        est = self.est
        est.counters.counts["gnss_kind_changes"] += 1
        old_level = self.level.pop(unit, None)
        self.positions.pop(unit, None)
        share = self.white.get((unit, kind))
        if share is not None:
            share.forget()                  # its last fix was before the other kind's spell
        if solution_rank(kind) > solution_rank(before):
            self.stepped_up[unit] = old_level
        else:
            self.stepped_up.pop(unit, None)
        est.log.info("%s: solution %s -> %s (a known step: the receiver's error starts again)",
                     unit, before, kind)

    def _widen_to_step(self, nu_p, Rp, fix, old_level: tuple | None) -> None:
        """The first fix of a better kind: where it puts the antenna is believed. If the gate
        would refuse it (the estimate was surer of itself than the old kind's fixes
        deserved), the position's covariance grows by the step, nu nu^T, so it is taken;
        counted in `counts.kind_steps_believed`, not as a widening. Only a step the old
        kind's fixes could have made (horizontally within STEP_BELIEVED_SIGMAS of their
        level and this fix's sigma), and once per receiver every STEP_BELIEVED_EVERY_S: a
        wrong integer fix is a step to a better kind too, and a flicker steps again and
        again. Otherwise the gate judges the fix as any other."""
        est, unit = self.est, fix.unit
        kf = est.kf
        d2 = quadratic(inverse_small(kf.position_innovation_cov(Rp, unit)), nu_p)
        if d2 <= self.settings.gate_chi2 or old_level is None:
            return
        step_h = math.hypot(nu_p[0], nu_p[1])
        var_h = max(old_level[0], old_level[1]) + max(float(Rp[0, 0]), float(Rp[1, 1]))
        if step_h > STEP_BELIEVED_SIGMAS * math.sqrt(var_h):
            est.log.info("%s: the step to a better solution (%.2f m) is beyond the old one's %.2f m: "
                         "left to the gate", unit, step_h, math.sqrt(var_h))
            return
        last = self.step_believed_t.get(unit)
        if last is not None and 0 <= fix.t - last < STEP_BELIEVED_EVERY_S * 1e9:
            est.log.info("%s: a step to a better solution %.1f s after the last one believed: left to the gate",
                         unit, (fix.t - last) * 1e-9)
            return
        self.step_believed_t[unit] = fix.t
        kf.inflate(0, nu_p)
        est.counters.counts["kind_steps_believed"] += 1
        est.log.info("%s: the step to a better solution (%.2f m) widens the position",
                     unit, math.sqrt(nu_p[0] ** 2 + nu_p[1] ** 2 + nu_p[2] ** 2))

    def _rests_on(self, fix) -> None:
        """The filter took this fix's position: the estimate rests on its solution."""
        self.solutions[fix.unit] = (fix.t, fix.kind, fix.diff_age_s)

    def _course_from_positions(self, fix, z, arm, white_cov, extra_var: float, imu_mode: bool) -> None:
        """A receiver without velocity: the body origin's velocity as the straight line
        through its last POSITION_COURSE_S of fixes (least squares; on an arc the line is
        parallel to the tangent halfway). Its direction goes to the heading filter, compared
        with the yaw halfway, when its speed is CHORD_SIGMAS times its own noise (short
        chords of noisy fixes point anywhere: a single pair did, and turned the yaw round);
        the velocity itself corrects the Kalman filter's at that time, as a Doppler velocity
        would, its covariance doubled: the fixes it comes from are also used as positions."""
        unit = fix.unit
        buf = self.positions.setdefault(unit, [])
        buf.append((fix.t, z[0] - arm[0], z[1] - arm[1], z[2] - arm[2]))
        span = (fix.t - buf[0][0]) * 1e-9
        if span < POSITION_COURSE_S or len(buf) < POSITION_COURSE_FIXES:
            if span > POSITION_COURSE_MAX_S:
                self.positions[unit] = [buf[-1]]    # a gap: start again
            return
        self.positions[unit] = []
        if span > POSITION_COURSE_MAX_S:
            return
        t = np.array([(b[0] - buf[0][0]) * 1e-9 for b in buf])
        tm = float(t.mean())
        dt = t - tm
        sxx = float(dt @ dt)
        v = np.array(buf)[:, 1:4].T @ dt / sxx      # E, N, U slopes
        cov = white_cov / sxx                       # of a slope through fixes: their white part
        t_mid = buf[0][0] + int(tm * 1e9)
        mid = self._state_at(t_mid)
        if mid is None:
            return
        est = self.est
        if imu_mode and est.kf.initialized:
            nu = [float(v[k] - mid[1][k]) for k in range(3)]
            _, ok, dx, _, d2 = est.kf.update_fix(None, None, nu, 2.0 * cov, None, self.settings.gate_chi2, unit)
            if dx is not None:
                est.corrected(dx)
            est.consistency.seen("velocity", d2, 3, self.settings.gate_chi2, judges=False)
            if not ok:
                est.counters.gnss("velocity_innovation")
        ve, vn = float(v[0]), float(v[1])
        if ve * ve + vn * vn < CHORD_SIGMAS ** 2 * float(cov[0, 0] + cov[1, 1]):
            return                                  # noise, not a direction
        est.heading.course((ve, vn), cov[:2, :2], mid[2], est.history, extra_var)

    def _disagreement(self, fix, z, Rp, arm, vel, velR, wander, at_least_s: float = 0.0) -> bool:
        """Usable fixes keep failing the innovation test: after gnss_reset_s (or
        `at_least_s`, for positions alone), believe GNSS. True if it did (position, velocity
        and yaw start again from this fix).

        A single wild fix is the receiver's fault; seconds of them are ours (a wrong
        velocity, a drift while coasting, a yaw gone wrong) or a jump the receiver really made.
        """
        if self.reject_since is None or fix.t - self.last_refused_t > self.est.gnss_timeout_ns:
            # (refusals before a spell without fixes are not this disagreement: the time
            # without fixes is no time GNSS disagreed)
            self.reject_since = fix.t
            self.last_refused_t = fix.t
            return False
        self.last_refused_t = fix.t
        limit = max(self.settings.gnss_reset_s, at_least_s)
        if (fix.t - self.reject_since) * 1e-9 <= limit:
            return False
        self._start_again(f"GNSS disagreed for {limit:g} s", fix, z, Rp, arm, vel, velR, wander)
        return True

    def _imu_contradicted(self, nu_v, vel_ok: bool) -> bool:
        """The filter's velocity, which the IMU drives, is more than IMU_CONTRADICTED_MPS off
        GNSS's horizontally at IMU_CONTRADICTED_FIXES fixes in a row."""
        if vel_ok or nu_v[0] * nu_v[0] + nu_v[1] * nu_v[1] < IMU_CONTRADICTED_MPS ** 2:
            self.contradicted = 0
            return False
        self.contradicted += 1
        return self.contradicted >= IMU_CONTRADICTED_FIXES

    def _start_again(self, why: str, fix, z, Rp, arm, vel, velR, wander) -> None:
        """Believe GNSS: position and velocity start again from this fix, the yaw from the
        next course, roll and pitch from a new alignment (the attitude that made the
        velocity go wrong may have gone wrong itself)."""
        est = self.est
        why = f"{why}: position, velocity and attitude reinitialised"
        est.counters.reset(why)
        est.log.warning("%s", why)
        est.kf.reset()
        est.history.clear()
        est.heading.forget()
        est.attitude.realign()
        self.reject_since = None
        self.contradicted = 0
        self.vel_refused.clear()
        for share in self.white.values():
            share.forget()
        if any(arm):                        # the yaw is forgotten, and the arm's direction with it
            lever = self.levers.get(fix.unit, self.lever_default)
            Rp = Rp + np.eye(3) * (lever[0] ** 2 + lever[1] ** 2 + lever[2] ** 2)
            arm = (0.0, 0.0, 0.0)
        self._initialize(fix, z, Rp, arm, vel, velR, wander)

    def _initialize(self, fix, z, Rp, arm, vel, velR, wander) -> None:
        """First usable fix: position (and velocity) straight from GNSS; the receiver's
        wandering error (sigmas `wander`) is in the position's error."""
        est = self.est
        if vel is None:
            vel, velR = (0.0, 0.0, 0.0), np.eye(3) * VEL_UNKNOWN_VAR       # unknown: a car, below 40 m/s
        t_state = est.timeline.t_state
        dt = 0.0 if t_state is None else max(0.0, (t_state - fix.t) * 1e-9)
        pos = [z[k] - arm[k] + vel[k] * dt for k in range(3)]
        kf = est.kf
        kf.reset()
        if self.settings.gnss_bias_tau_s > 0:
            kf.receiver(fix.unit, wander, fix.kind)
        kf.initialize(pos, Rp, vel, velR, fix.unit)
        if est.attitude.aligned:
            kf.retilt(est.tilt_sigma_rad())
        self.arm_known = any(arm) or not any(self.levers.get(fix.unit, self.lever_default))
        est.timeline.catch_up(fix.t)
        est.history.clear()
        est.counters.gnss_used += 1
        self._rests_on(fix)
        est.log.info("position initialised from %s: ENU %.2f %.2f %.2f", fix.unit, *pos)
        est.heading.course(vel, velR, est.attitude.yaw, est.history)

    def _coast_to(self, t: int) -> None:
        """No IMU: move the state to the fix's time with the constant-velocity model."""
        est = self.est
        dt = est.timeline.coast_to(t)
        if dt <= 0.0:
            return
        if est.kf.initialized:
            est.kf.move(0.0, 0.0, 0.0, dt)
        if est.heading.filter.valid:
            est.heading.filter.coast(dt)
        est.history.clear()
        for share in self.white.values():
            share.forget()

    def _state_at(self, t: int):
        """(p, v, yaw) at time t: now, or from the history for a late fix."""
        est = self.est
        x = est.kf.x
        yaw_now = est.attitude.yaw
        t_state = est.timeline.t_state
        if t_state is None or t >= t_state:
            return x[0:3], x[3:6], yaw_now
        then = est.history.at(t)
        if then is not None:
            return then
        dt = (t_state - t) * 1e-9
        if dt <= self.settings.late_window_s:
            # older than the history: just after (re)initialisation. Extrapolate back.
            return [x[k] - x[3 + k] * dt for k in range(3)], x[3:6], yaw_now
        return None


def _floors(given: dict) -> dict[str, tuple[float, float, float]]:
    """`gnss_sigma_floor_m` as sigmas along E, N, U per solution kind."""
    floors = {}
    for kind, hv in given.items():
        if solution_rank(kind) < 0:
            raise ValueError(f"gnss_sigma_floor_m.{kind}: a solution kind, one of {', '.join(SOLUTION_KINDS)}")
        if len(hv) != 2 or min(hv) < 0.0:
            raise ValueError(f"gnss_sigma_floor_m.{kind}: [horizontal, vertical] in m, got {list(hv)!r}")
        floors[kind] = (float(hv[0]), float(hv[0]), float(hv[1]))
    return floors
