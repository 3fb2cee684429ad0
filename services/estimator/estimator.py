"""The estimator: attitude, position and velocity from IMU samples and GNSS fixes.

A plain class, no zenoh: feed it samples as dicts in the agreed schemas (viena.imu.sample/1,
viena.gnss.fix/1), read `state()`. The same code runs in the live service and offline
over a recording:

    est = Estimator({"origin": [38.7369, -9.1395, 100.0]})
    for sample in merged_by_time(imu_samples, gnss_fixes):
        est.add_imu(sample) if "accel_mps2" in sample else est.add_gnss(sample)
    est.state()["enu_m"]

This class only wires the parts together, one idea each (docs/estimator.md#the-parts):

    inputs.py       what is accepted (through the schema modules' readers)
    timeline.py     when each input is used: ordering, late and early fixes, the clock
    attitude.py     Madgwick, alignment, motion compensation          (madgwick.py)
    heading.py      whether the yaw is known, and the course over ground
    standstill.py   is the car standing, and the gyro's bias while it is
    constraints.py  zero velocity and the non-holonomic pseudo-measurements
    kalman.py       the Kalman filter: position, velocity, accelerometer bias
    history.py      the last second of the trajectory, for late fixes
    gnss_update.py  a fix into the filters: gates, lever arm, resets
    output.py       the state sample                                    (state.py)

A filter that diverges is reset, says why and realigns; counters survive it.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from viena.common.geodesy import LocalFrame
from viena.common.settings import from_mapping
from viena.services.estimator.attitude import Attitude
from viena.services.estimator.consistency import Consistency
from viena.services.estimator.constraints import Constraints
from viena.services.estimator.counters import Counters
from viena.services.estimator.gnss_update import POSITION_COURSE_MAX_S, GnssUpdate
from viena.services.estimator.heading import Heading
from viena.services.estimator.history import TrajectoryHistory
from viena.services.estimator.inputs import ImuLimits, Rejected, gnss_fix, imu_sample
from viena.services.estimator.kalman import Diverged, KalmanNoise, NavKalman
from viena.services.estimator.mount import MountHint
from viena.services.estimator.output import build_state
from viena.services.estimator.settings import EstimatorSettings
from viena.services.estimator.standstill import Standstill
from viena.services.estimator.timeline import NEW_TIMELINE, NewTimeline, Timeline

_G = 9.80665
#: a step between IMU samples longer than this and the attitude aligns again
_REALIGN_GAP_S = 2.0
#: an alignment knows the car's speed when a GNSS velocity came this recently (ns): within a
#: second, or a 1 Hz receiver's never would be, a fix always being up to 1 s old
_ALIGN_SPEED_AGE_NS = 1_500_000_000


class Estimator:
    """Feed `add_imu(sample)` and `add_gnss(fix)`; read `state()`. Not thread-safe: one
    thread feeds it (the service's worker)."""

    def __init__(self, settings: EstimatorSettings | Mapping | None = None,
                 clock: Callable[[], int] | None = None, log: logging.Logger | None = None):
        s: EstimatorSettings = settings if isinstance(settings, EstimatorSettings) \
            else from_mapping(EstimatorSettings, settings, "estimator settings")
        self.settings = s
        self.log = log or logging.getLogger("viena.estimator")
        self._limits = ImuLimits(s.max_accel_g * _G, math.radians(s.max_gyro_dps))
        self._imu_gap_s = s.imu_gap_s
        self._still_mps = s.still_speed_mps
        self.gnss_timeout_ns = int(s.gnss_timeout_s * 1e9)
        if len(s.accel_bias_sigma_mps2) != 3:
            raise ValueError("accel_bias_sigma_mps2 is [x right, y forward, z up] in m/s^2")
        self._noise = KalmanNoise(
            s.accel_psd, s.accel_bias_walk_psd, s.free_accel_psd, tuple(s.accel_bias_sigma_mps2),
            s.tilt_walk_psd, math.radians(s.tilt_sigma_deg), s.gnss_bias_tau_s,
            s.gnss_common_fraction, s.gnss_consider_errors)
        #: standstill thresholds learnt (kept across resets): see Standstill.learnt
        self._quiet: tuple[float | None, float | None, bool] = (None, None, False)
        self.accel_enu = (0.0, 0.0, 0.0)    # the car's acceleration by the IMU, last sample
        self.counters = Counters()
        self.timeline = Timeline(s, clock)
        self.frame: LocalFrame | None = None
        self.origin_source = "none"
        self._gravity = _G
        if s.origin:
            if len(s.origin) != 3:
                raise ValueError("origin is [lat_deg, lon_deg, height_m]")
            self.set_origin(LocalFrame(*s.origin), "config")
        self._seq = 0
        #: how the IMU sits in the car: learnt over the whole drive, kept through resets
        self.mount = MountHint(s.imu_mount_sigma_deg, self.log)
        # how the filter judges each source, and itself
        self.consistency = Consistency(inflate_after_s=0.5 * s.gnss_reset_s)
        self.gnss = GnssUpdate(self)
        self.standstill: Standstill     # made by _restart, as are the other parts
        self._restart()

    # -- public ----------------------------------------------------------------------------
    def add_imu(self, sample) -> bool:
        """Use one viena.imu.sample/1; False if it was rejected (and counted)."""
        timeline = self.timeline
        try:
            imu = imu_sample(sample, self._limits)
            t = imu.t
            if timeline.check_future(t, imu.unit):
                self._new_timeline("times jumped ahead")
            new_unit = imu.unit != timeline.imu_unit
            dt, takeover = timeline.admit_imu(imu.unit, t)
        except Rejected as exc:
            self._refused(exc)
            return False
        except NewTimeline as exc:
            self.counters.input(exc.rejected)
            self._new_timeline(str(exc))
            return False
        if new_unit:
            if takeover:
                self.attitude.realign()
            self.log.info("IMU unit %s drives the estimator", imu.unit)
        self.counters.counts["imu"] += 1
        ax, ay, az = imu.accel_mps2
        gx, gy, gz = imu.gyro_radps
        try:
            self._imu_step(t, dt, ax, ay, az, gx, gy, gz, imu.mag_T)
        except Diverged as exc:
            self.reset(f"diverged: {exc}")
        for fix in timeline.due(t):
            self.gnss.use(fix)
        return True

    def add_gnss(self, sample) -> bool:
        """Use one viena.gnss.fix/1; False if it was rejected as bad or late input.

        A well-formed fix that the filter refuses (no solution, large sigma, failed
        innovation test) returns True and is counted in `gnss_rejected`.
        """
        timeline = self.timeline
        try:
            fix = gnss_fix(sample)
            if timeline.check_future(fix.t, fix.unit):
                self._new_timeline("times jumped ahead")
            timeline.admit_fix(fix.unit, fix.t)
        except Rejected as exc:
            self._refused(exc)
            return False
        self.counters.counts["gnss"] += 1
        for due in timeline.schedule(fix):
            self.gnss.use(due)
        return True

    def _refused(self, exc: Rejected) -> None:
        """Count a refused input; say which source sends bad stamps (at its 1st, 10th,
        100th ... refusal: a log that grows with the trouble, not with the samples)."""
        n = self.counters.input(exc.reason, exc.source)
        if n and math.log10(n) % 1.0 == 0.0:
            self.log.warning("%s: input refused for its time (%s), %d so far", exc.source, exc, n)

    def state(self) -> dict:
        """The state as a viena.estimator.state/2 sample. Never carries a NaN: if the
        filter produced one, it resets and reports the reset state instead."""
        self._seq += 1
        try:
            out, numbers = build_state(self, self._seq)
            total = sum(numbers)
            reason = None if total - total == 0.0 else "a state value was not finite"
        except (Diverged, ValueError) as exc:
            reason = str(exc)
        if reason is not None:
            self.reset(f"diverged: {reason}")
            self._seq += 1
            out, _ = build_state(self, self._seq)
        return out

    @property
    def imu_live(self) -> bool:
        """An IMU sample came within imu_timeout_s of the state's time."""
        return self.timeline.imu_live

    @property
    def t(self) -> int | None:
        """Time of the state, ns UTC."""
        return self.timeline.t_state

    @property
    def imu_unit(self) -> str | None:
        return self.timeline.imu_unit

    # the counters, as the state reports them
    counts = property(lambda self: self.counters.counts)
    gnss_used = property(lambda self: self.counters.gnss_used)
    gnss_rejected = property(lambda self: self.counters.gnss_rejected)
    input_rejected = property(lambda self: self.counters.input_rejected)
    time_refused = property(lambda self: self.counters.time_refused)
    last_reset = property(lambda self: self.counters.last_reset)

    # -- life ------------------------------------------------------------------------------
    def _restart(self) -> None:
        """Forget the estimate (not the counters, the origin nor the times): align again."""
        s = self.settings
        self.attitude = Attitude(s, self.counters.counts, self.log)
        self.heading = Heading(s, self.attitude, self.counters, self.log, self.consistency)
        self.kf = NavKalman(self._noise, tilt=True)
        if getattr(self, "standstill", None) is not None:
            self._quiet = self.standstill.learnt
        self.standstill = Standstill(s, self._quiet)
        self.constraints = Constraints(s, self.counters.counts, self.mount)
        self._mag = None                    # the last magnetometer reading
        # the last second for late fixes, or the span a position-only receiver's course
        # is taken over (its middle is compared with the yaw then)
        self.history = TrajectoryHistory(max(self.timeline.late_ns, int(POSITION_COURSE_MAX_S * 1e9)))
        self.consistency.restart()
        self.gnss.restart()

    def reset(self, reason: str) -> None:
        """Something went wrong with the estimate: say why, and start it again."""
        self.counters.reset(reason)
        self.log.warning("estimator reset (%s): realigning", reason)
        self._restart()

    def _new_timeline(self, why: str) -> None:
        """Inputs keep disagreeing with the time so far: the time so far was the wrong one."""
        self.timeline.restart()
        self.gnss.forget_times()
        self.reset(f"{why} for {NEW_TIMELINE} inputs in a row: a new timeline")

    def set_origin(self, frame: LocalFrame, source: str) -> None:
        self.frame, self.origin_source = frame, source
        self._gravity = self._noise.gravity = frame.gravity_mps2
        self.log.info("ENU origin (%s): lat %.8f lon %.8f h %.3f", source, *frame.origin)

    def corrected(self, dx) -> None:
        """The Kalman filter corrected its state by dx: the past trajectory moves with it,
        and the tilt it found goes to the attitude."""
        self.history.correct(dx[0:3], dx[3:6])
        self.attitude.correct_tilt(*self.kf.take_tilt())

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
        P = self.kf.P
        r = att.rot
        # the forward (body y) and right (body x) axes, horizontally, in ENU
        f = (r[1], r[4])
        g = (r[0], r[3])
        pee, pen, pnn = float(P[9, 9]), float(P[9, 10]), float(P[10, 10])
        about = [f[0] * f[0] * pee + 2 * f[0] * f[1] * pen + f[1] * f[1] * pnn,
                 g[0] * g[0] * pee + 2 * g[0] * g[1] * pen + g[1] * g[1] * pnn]
        return about

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
        standstill = self.standstill
        standstill.update(dt, gx, gy, gz, fx, fy, fz, att.rot, self._gravity, speed_still, att,
                          self.gnss.doppler.span(t))
        heading = self.heading
        history = self.history
        if mag is not None:
            self._mag = mag

        if not att.aligned:
            speed, known = 0.0, False
            if kf.initialized:
                speed = math.hypot(kx[3], kx[4])
                # a GNSS velocity came within the last fix or so (the filter's own variance
                # grows fast while nothing drives it during an alignment)
                speed_t = self.gnss.speed_t
                known = speed_t is not None and 0 <= t - speed_t < _ALIGN_SPEED_AGE_NS
            att.gather(t, fx, fy, fz, gx, gy, gz, mag, heading.filter.valid, speed, known,
                       standstill.gnss_moving)
            if kf.initialized:
                if dt_state > 0.0:
                    kf.move(0.0, 0.0, 0.0, dt_state)
                if att.aligned:             # a new attitude: the filter's tilt starts again
                    kf.retilt(self.tilt_sigma_rad())
                history.append(t, kf.x, att.yaw)
            return

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
        c = self.constraints
        if t >= c.next_t:
            c.next_t = t + c.interval_ns
            att.tilt_residual(c.interval_ns * 1e-9)
            if aided and att.beta_aided == 0.0 and self._mag is not None and att.use_mag \
                    and att.mag_plausible(self._mag, fx, fy, fz):
                heading.magnetometer(self._mag, history)
            if t - c.last_t >= c.interval_ns:
                dx = c.apply_alone(kf, att, heading, standstill.still, self.tilt_var()[1])
                if dx is not None:
                    self.corrected(dx)
        history.append(t, kf.x, att.yaw)
