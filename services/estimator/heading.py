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
        if gate_chi2 is not None and e * e > gate_chi2 * s:
            return None
        k0, k1 = self.p00 / s, self.p01 / s
        self.bias += k1 * e
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.p00 = (1 - k0) * p00
        self.p01 = (1 - k0) * p01
        self.p11 = p11 - k1 * p01
        return k0 * e
