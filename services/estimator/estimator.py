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
    navigation.py   the half of this class that changes the filters: the IMU step, and
                    what the GNSS side decided applied (no other part updates the Kalman filter)
    kalman.py       the Kalman filter: position, velocity, accelerometer bias (kalman_update.py)
    history.py      the last second of the trajectory, for late fixes
    gnss_update.py  a fix into the filters: admit, measure, update, judge; it decides
                    (gnss_gates.py, fix_measurement.py, gnss_judgement.py, gnss_course.py)
    output.py       the state sample (schema: viena.common.samples.estimator)

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
from viena.services.estimator.gnss_course import POSITION_COURSE_MAX_S
from viena.services.estimator.gnss_judgement import solution
from viena.services.estimator.gnss_update import GnssUpdate
from viena.services.estimator.heading import UNKNOWN_VAR, Heading
from viena.services.estimator.history import TrajectoryHistory
from viena.services.estimator.inputs import ImuLimits, Rejected, gnss_fix, imu_sample
from viena.services.estimator.kalman import Diverged, KalmanNoise, NavKalman
from viena.services.estimator.mount import MountHint
from viena.services.estimator.navigation import Navigation
from viena.services.estimator.output import TIME_FLOOR_NS, StateView, build_state, mode
from viena.services.estimator.settings import EstimatorSettings
from viena.services.estimator.standstill import Standstill
from viena.services.estimator.timeline import NEW_TIMELINE, NewTimeline, Timeline

_G = 9.80665


class Estimator(Navigation):
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
            out, numbers = build_state(self._view(), self._seq)
            total = sum(numbers)
            reason = None if total - total == 0.0 else "a state value was not finite"
        except (Diverged, ValueError) as exc:
            reason = str(exc)
        if reason is not None:
            self.reset(f"diverged: {reason}")
            self._seq += 1
            out, _ = build_state(self._view(), self._seq)
        return out

    def _view(self) -> StateView:
        """What the state sample is made of, read off the parts."""
        kf, att, heading, gnss, timeline = self.kf, self.attitude, self.heading, self.gnss, self.timeline
        t = timeline.t_state or TIME_FLOOR_NS
        # [yaw, pitch (about the right axis), roll (about forward)]
        tilt = self.tilt_var() if att.aligned else (UNKNOWN_VAR, UNKNOWN_VAR)
        att_var = [heading.yaw_var(), tilt[1], tilt[0]]
        doing = mode(timeline.t_state, timeline.imu_live, kf.initialized, att.aligned,
                     gnss.gates.last_fix_t.values(), self.gnss_timeout_ns)
        return StateView(
            t=t, mode=doing, x=kf.x if kf.initialized else None, P=kf.P if kf.initialized else None,
            q=att.att.q, att_var=att_var, rate=att.rate, gyro_bias=att.gyro_bias, aligned=att.aligned,
            heading_valid=heading.valid, heading_source=heading.source, still=self.standstill.still,
            imu_live=timeline.imu_live, gnss_live=gnss.gates.live_units(t, self.gnss_timeout_ns),
            frame=self.frame, origin_source=self.origin_source, counters=self.counters,
            offset_hint_s=gnss.timing.offset_s, mount_hint_deg=self.mount.hint_deg(),
            consistency=self.consistency.report(), admission=gnss.admission.report(),
            solution=solution(gnss.solutions, t, self.gnss_timeout_ns))

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
