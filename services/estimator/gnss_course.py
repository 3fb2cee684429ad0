"""What a receiver's fixes say of the car's course, for the heading filter.

- a velocity the filter took: its course, compared with the yaw at the velocity's time;
- a velocity refused COURSE_AFTER_REFUSALS times in a row may be right and the yaw wrong:
  its course anyway, as uncertain as the disagreement is large;
- a receiver without velocity (NMEA GGA): the body origin's velocity as the straight line
  through the last POSITION_COURSE_S of its fixes (least squares; on an arc the line is
  parallel to the tangent halfway), `PositionCourse`.

`Courses` decides; the Estimator's `Navigation` half (navigation.py) applies.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:                       # the estimator hands itself in: types only, no cycle
    from viena.services.estimator.estimator import Estimator

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


class Courses:
    """Each receiver's velocities refused in a row, and its recent positions."""

    def __init__(self, gate_chi2: float) -> None:
        self.gate_chi2 = gate_chi2
        self.restart()

    def restart(self) -> None:
        self.vel_refused: dict[str, int] = {}
        self.positions = PositionCourse()

    def use(self, nav: Estimator, fix, z, arm, white_cov, vel, velR, nu_v, vel_ok: bool, yaw, course_var: float,
            imu_mode: bool) -> None:
        """A fix's velocity (covariance velR, innovation nu_v, taken or not; yaw then) or,
        for a receiver without one, its position z less the arm: a course for `nav`'s
        heading filter, with `course_var` added for the IMU clock's uncertainty."""
        unit = fix.unit
        if vel_ok:
            self.vel_refused[unit] = 0
            nav.course(vel, velR, yaw, course_var)
        elif nu_v is not None:
            n = self.vel_refused[unit] = self.vel_refused.get(unit, 0) + 1
            assert vel is not None, "an innovation nu_v comes from a velocity"
            speed2 = vel[0] * vel[0] + vel[1] * vel[1]
            if n >= COURSE_AFTER_REFUSALS and speed2 > 0.0:
                course_var += (nu_v[0] * nu_v[0] + nu_v[1] * nu_v[1]) / speed2
                nav.course(vel, velR, yaw, course_var)
        elif vel is None:
            self._from_positions(nav, fix, z, arm, white_cov, course_var, imu_mode)

    def _from_positions(self, nav, fix, z, arm, white_cov, extra_var: float, imu_mode: bool) -> None:
        """The line through a receiver's positions: its direction goes to the heading
        filter, compared with the yaw halfway, when its speed is CHORD_SIGMAS times its own
        noise (short chords of noisy fixes point anywhere: a single pair did, and turned the
        yaw round); the velocity itself corrects the Kalman filter's at that time, as a
        Doppler velocity would, its covariance doubled: the fixes are also used as positions."""
        unit = fix.unit
        line = self.positions.add(unit, fix.t, (z[0] - arm[0], z[1] - arm[1], z[2] - arm[2]))
        if line is None:
            return
        v, sxx, t_mid = line
        cov = white_cov / sxx                       # of a slope through fixes: their white part
        mid = nav.state_at(t_mid)
        if mid is None:
            return
        if imu_mode and nav.kf.initialized:
            nu = [float(v[k] - mid[1][k]) for k in range(3)]
            _, ok, _, d2 = nav.update_by_fix(None, None, nu, 2.0 * cov, None, unit)
            nav.consistency.seen("velocity", d2, 3, self.gate_chi2, judges=False)
            if not ok:
                nav.counters.gnss("velocity_innovation")
        ve, vn = float(v[0]), float(v[1])
        if ve * ve + vn * vn < CHORD_SIGMAS ** 2 * float(cov[0, 0] + cov[1, 1]):
            return                                  # noise, not a direction
        nav.course((ve, vn), cov[:2, :2], mid[2], extra_var)


class PositionCourse:
    """Each position-only receiver's recent positions (body origin, ENU)."""

    def __init__(self) -> None:
        self.positions: dict[str, list] = {}

    def forget(self, unit: str | None = None) -> None:
        if unit is None:
            self.positions.clear()
        else:
            self.positions.pop(unit, None)

    def add(self, unit: str, t: int, p) -> tuple[np.ndarray, float, int] | None:
        """One more position of `unit` at t; once they span POSITION_COURSE_S (and are
        enough), the line through them: (velocity E N U, the sum of the squared time
        offsets from their middle (s^2: a slope's variance is a fix's over it), the middle
        time), and the next line starts afresh. None until then, or after a gap."""
        buf = self.positions.setdefault(unit, [])
        buf.append((t, p[0], p[1], p[2]))
        span = (t - buf[0][0]) * 1e-9
        if span < POSITION_COURSE_S or len(buf) < POSITION_COURSE_FIXES:
            if span > POSITION_COURSE_MAX_S:
                self.positions[unit] = [buf[-1]]    # a gap: start again
            return None
        self.positions[unit] = []
        if span > POSITION_COURSE_MAX_S:
            return None
        ts = np.array([(b[0] - buf[0][0]) * 1e-9 for b in buf])
        tm = float(ts.mean())
        dt = ts - tm
        sxx = float(dt @ dt)
        v = np.array(buf)[:, 1:4].T @ dt / sxx      # E, N, U slopes
        return v, sxx, buf[0][0] + int(tm * 1e9)
