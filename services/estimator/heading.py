"""Yaw from the GNSS course over ground, for IMUs without a usable magnetometer.

A car's rear axle moves along the car (no side slip at the speeds we drive), so the
horizontal velocity of the body origin points where the car points:
body y = [-sin yaw, cos yaw] in ENU, hence yaw = atan2(-v_E, v_N), or that plus 180 deg
when reversing. A two-state Kalman filter, [yaw, gyro z bias], weighs each course by
its noise, sigma_v / speed, against the gyro's drift, and learns the gyro's bias on the
way; its corrections turn the attitude about the world up axis.
"""
from __future__ import annotations

import math

from viena.common.rotation import wrap_angle

#: the variance of an angle we know nothing about (uniform on +-pi)
UNKNOWN_VAR = math.pi ** 2 / 3.0


def course_yaw(ve: float, vn: float) -> float:
    """Yaw (ENU, CCW, 0 = North) of a car moving forward with horizontal velocity (ve, vn)."""
    return math.atan2(-ve, vn)


class HeadingFilter:
    """[yaw error, gyro z bias] with covariance in plain floats."""

    def __init__(self, gyro_psd: float = 1e-6, bias_walk_psd: float = 1e-9,
                 bias_sigma0: float = math.radians(0.5)):
        self.gyro_psd = gyro_psd            # (rad/s)^2/Hz
        self.bias_walk_psd = bias_walk_psd  # (rad/s)^2/s
        self.bias_sigma0 = bias_sigma0
        self.bias = 0.0
        self.valid = False
        self.p00, self.p01, self.p11 = UNKNOWN_VAR, 0.0, bias_sigma0 ** 2
        #: gyro time not yet propagated: add to it per sample, the filter catches up when used
        self.pending_s = 0.0

    def reset(self) -> None:
        self.valid = False
        self.p00, self.p01, self.p11 = UNKNOWN_VAR, 0.0, self.bias_sigma0 ** 2
        self.pending_s = 0.0

    def set(self, var: float) -> None:
        """The yaw was just set by a measurement of this variance."""
        self.valid = True
        self.p00, self.p01 = var, 0.0
        self.pending_s = 0.0

    @property
    def yaw_var(self) -> float:
        self.propagate()
        return min(self.p00, UNKNOWN_VAR) if self.valid else UNKNOWN_VAR

    def propagate(self) -> None:
        """Over the pending gyro time T: yaw' = omega - bias, F = [[1, -T], [0, 1]]."""
        dt = self.pending_s
        if dt <= 0.0:
            return
        self.pending_s = 0.0
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.p00 = p00 - 2 * dt * p01 + dt * dt * p11 + self.gyro_psd * dt
        self.p01 = p01 - dt * p11
        self.p11 = p11 + self.bias_walk_psd * dt

    def coast(self, dt: float, turn_psd: float = 0.25) -> None:
        """No gyro (GNSS only): the yaw may turn as a car turns, (0.5 rad/s)^2/Hz."""
        self.propagate()
        self.p00 = min(self.p00 + turn_psd * dt, UNKNOWN_VAR)

    def correct(self, innovation: float, var: float, gate_chi2: float | None = None):
        """Measured minus estimated yaw (rad), wrapped. Returns the yaw correction (rad)
        to apply to the attitude, or None if the course was rejected by the gate."""
        self.propagate()
        e = wrap_angle(innovation)
        s = self.p00 + var
        self.last_d2 = e * e / s                   # its NIS, for consistency.py
        if gate_chi2 is not None and e * e > gate_chi2 * s:
            return None
        k0, k1 = self.p00 / s, self.p01 / s
        self.bias += k1 * e
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.p00 = (1 - k0) * p00
        self.p01 = (1 - k0) * p01
        self.p11 = p11 - k1 * p01
        return k0 * e


class Heading:
    """Whether the yaw is known and how well, and what corrects it: the course over ground,
    and the magnetometer while Madgwick leaves the yaw alone (GNSS-aided driving).

    The yaw itself is the attitude's. Each correction goes through the heading filter,
    turns the attitude about up, and feeds the learnt gyro z bias back into the gyro's
    (bounded by `max_gyro_bias_dps`: a wrong time or a wild course must not teach the gyro
    a bias it cannot have)."""

    def __init__(self, settings, attitude, counters, log, judge=None):
        self.settings, self.attitude, self.counters, self.log = settings, attitude, counters, log
        self.judge = judge                  # consistency.py: each correction's NIS
        self.filter = HeadingFilter(settings.gyro_noise_psd, settings.gyro_bias_walk_psd)
        self.max_bias = math.radians(settings.max_gyro_bias_dps)
        self.mag_var = math.radians(settings.mag_yaw_sigma_deg) ** 2
        self.course_seen = False            # a course corrected the yaw
        self.mag_seen = False               # the magnetometer did, through this filter

    @property
    def valid(self) -> bool:
        return self.filter.valid or self.attitude.mag_heading

    @property
    def source(self) -> str:
        mag = self.mag_seen or self.attitude.mag_heading
        course = self.course_seen and self.filter.valid
        return "mag+course" if mag and course else "mag" if mag else "course" if course else "none"

    def yaw_var(self) -> float:
        if self.filter.valid:
            return self.filter.yaw_var
        return math.radians(3.0) ** 2 if self.attitude.mag_heading else UNKNOWN_VAR

    def forget(self) -> None:
        """The yaw is no longer to be trusted (GNSS has disagreed for long): the next
        course sets it afresh."""
        self.filter.reset()
        self.attitude.mag_heading = False
        self.course_seen = self.mag_seen = False

    def course(self, vel, vel_cov, yaw_then: float, history, extra_var: float = 0.0) -> None:
        """Yaw from the direction of travel (ENU velocity `vel`, covariance `vel_cov`), when
        moving fast enough for it to mean something; `yaw_then` is the yaw at the velocity's
        time, `history` the trajectory the correction also turns; `extra_var` what else
        makes the course uncertain (a time offset in a turn), rad^2."""
        s = self.settings
        if not s.course_heading:
            return
        speed = math.hypot(vel[0], vel[1])
        if speed < s.course_min_speed_mps:
            return
        var = 0.5 * float(vel_cov[0, 0] + vel_cov[1, 1]) / (speed * speed) + extra_var
        measured = course_yaw(vel[0], vel[1])
        h, att = self.filter, self.attitude
        if h.valid or att.mag_heading:
            e = wrap_angle(measured - yaw_then)
            if abs(e) > 0.5 * math.pi and self.yaw_var() < math.radians(30.0) ** 2:
                e = wrap_angle(e + math.pi)        # reversing: the car points against its course
            if not h.valid:
                h.set(self.yaw_var())
            corr = h.correct(e, var, s.gate_chi2)
            if self.judge is not None:
                self.judge.seen("course", h.last_d2, 1, s.gate_chi2)
                if self.judge.refused("course", "course", corr is not None):
                    # courses refused again and again: the yaw is less sure than the filter
                    # thinks (consistency.py); widen it by the disagreement and take this one
                    h.p00 += e * e
                    self.counters.counts["inflations"] += 1
                    corr = h.correct(e, var, s.gate_chi2)
            if corr is None:
                self.counters.gnss("course_innovation")
                return
        else:
            corr = wrap_angle(measured - yaw_then)
            h.set(var)
            self.log.info("yaw %.1f deg from the course over ground at %.1f m/s",
                          math.degrees(wrap_angle(att.yaw + corr)), speed)
        self.counters.counts["course_used"] += 1
        self.course_seen = True
        self._turn(corr, history)

    def magnetometer(self, mag, history) -> None:
        """Yaw from the field's horizontal direction, the attitude's tilt taken as right:
        the field turned into ENU by the attitude points where the declination says, or
        the yaw is off by the difference. (Madgwick's MARG step does this itself while it
        levels; this is for when it does not.)"""
        att = self.attitude
        r = att.rot
        mx, my, mz = mag
        he = r[0] * mx + r[1] * my + r[2] * mz
        hn = r[3] * mx + r[4] * my + r[5] * mz
        if he * he + hn * hn == 0.0:
            return
        # magnetic north is the declination D east of true north: azimuths counted CCW
        d = att.declination
        e = wrap_angle(math.atan2(math.cos(d), math.sin(d)) - math.atan2(hn, he))
        h = self.filter
        if not h.valid:
            h.set(self.yaw_var())
        corr = h.correct(e, self.mag_var, self.settings.gate_chi2)
        if self.judge is not None:
            self.judge.seen("heading", h.last_d2, 1, self.settings.gate_chi2)
        if corr is None:
            self.counters.counts["mag_rejected"] += 1
            return
        self.mag_seen = True
        self._turn(corr, history)

    def _turn(self, corr: float, history) -> None:
        """Apply a yaw correction, and what the heading filter learnt of the gyro's bias."""
        h, att = self.filter, self.attitude
        b = att.gyro_bias
        b[2] = max(-self.max_bias, min(self.max_bias, b[2] + h.bias))
        h.bias = 0.0
        att.rotate_yaw(corr)
        history.correct(dyaw=corr)
