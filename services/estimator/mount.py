"""How the IMU sits in the car, as the GNSS velocity sees it.

The non-holonomic constraint says the car moves along its own forward axis; the estimator
applies it along the IMU's axes. An IMU turned against the car (a phone on a windscreen,
a board mounted a few degrees off, a mount calibration never made) then has the
constraint fight GNSS: 4 degrees of pitch at 17 m/s is 1.2 m/s of "vertical" velocity that
the constraint (0.1 m/s) removes and every GNSS velocity puts back. Before this module
the filter refused those velocities and reset itself over and over.

While the car drives straight at speed, the GNSS velocity turned into the IMU's axes by
the attitude points along the car's forward axis: its angles above and beside the IMU's
forward axis are the mount's pitch and yaw. They are averaged over the drive, with the
uncertainty of the average; the constraint is applied along the car's axes so found, and
widened by what is still unknown of them (speed x angle sigma). The state reports them
(`imu_mount_hint_deg`) and the log says once when they call for `viena calibrate imu mount`.

The yaw is seen only when the heading does not itself come from the course (a
magnetometer); with the course heading the IMU's forward axis is put along the velocity by
construction, so its yaw part stays at zero and the pitch is what matters.
"""
from __future__ import annotations

import math

#: angles are learnt from fixes at least this fast (m/s) ...
MIN_SPEED_MPS = 3.0
#: ... while the car turns slower than this (rad/s): in a turn the rear axle's velocity
#: is along the car, but the IMU's point may slide sideways with the turn
MAX_TURN_RADPS = 0.1
#: the average forgets over about this many fixes (a mount does not move; a realignment does)
AVERAGE_FIXES = 400
#: one fix's angle is believed to this sigma (rad): GNSS velocity noise, vibration, tilt
ONE_FIX_SIGMA_RAD = math.radians(1.5)
#: a mount this far off (deg), known this well, is worth saying so
REPORT_DEG = 1.0


class MountHint:
    """The IMU's pitch and yaw against the car's forward axis, from GNSS velocity."""

    def __init__(self, prior_sigma_deg: float, log=None):
        self.prior_var = math.radians(prior_sigma_deg) ** 2
        self.log = log
        self.n = 0
        self.pitch = self.yaw = 0.0            # rad
        self._sq = [0.0, 0.0]                  # running mean of the squares, for the spread
        self.reported = False

    @property
    def var(self) -> float:
        """Variance of the angles (rad^2): the prior, shrunk by the fixes seen, never
        below what their spread says."""
        if self.n == 0 or self.prior_var == 0.0:
            return self.prior_var
        spread = max(self._sq[0] - self.pitch ** 2, self._sq[1] - self.yaw ** 2, ONE_FIX_SIGMA_RAD ** 2)
        n = min(self.n, AVERAGE_FIXES)
        return 1.0 / (1.0 / self.prior_var + n / spread)

    def observe(self, r, vel_enu, rate_z: float, yaw_from_course: bool) -> None:
        """A GNSS velocity (ENU, at the body origin) with the attitude `r` (body -> ENU).
        With a prior sigma of 0 (the mount is calibrated and trusted) nothing is learnt."""
        if self.prior_var == 0.0:
            return
        ve, vn, vu = vel_enu
        if ve * ve + vn * vn < MIN_SPEED_MPS ** 2 or abs(rate_z) > MAX_TURN_RADPS:
            return
        ux = r[0] * ve + r[3] * vn + r[6] * vu
        uy = r[1] * ve + r[4] * vn + r[7] * vu
        uz = r[2] * ve + r[5] * vn + r[8] * vu
        if uy <= 0.0:                           # reversing, or a yaw gone wrong
            return
        pitch = math.atan2(uz, uy)
        yaw = 0.0 if yaw_from_course else math.atan2(-ux, uy)
        self.n += 1
        k = 1.0 / min(self.n, AVERAGE_FIXES)
        self.pitch += k * (pitch - self.pitch)
        self.yaw += k * (yaw - self.yaw)
        self._sq[0] += k * (pitch * pitch - self._sq[0])
        self._sq[1] += k * (yaw * yaw - self._sq[1])
        if not self.reported and self.log is not None and self.n >= 40:
            big = max(abs(self.pitch), abs(self.yaw))
            if math.degrees(big) > REPORT_DEG and big > 3.0 * math.sqrt(self.var):
                self.reported = True
                self.log.warning("the IMU sits %.1f deg pitched and %.1f deg turned against the car's motion "
                                 "(GNSS velocity in its axes, %d fixes): its mount is not set; the estimator "
                                 "allows for it (viena calibrate imu mount sets it)",
                                 math.degrees(self.pitch), math.degrees(self.yaw), self.n)

    def hint_deg(self) -> list[float] | None:
        """[yaw, pitch] of the car's forward axis in the IMU's axes, or None before any fix."""
        if self.n == 0:
            return None
        return [math.degrees(self.yaw), math.degrees(self.pitch)]

    def axes(self, r) -> tuple[tuple, tuple]:
        """The car's right and up axes in ENU, as the IMU's turned by the mount angles."""
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        # right: x cos(yaw) + y sin(yaw); up: z cos(pitch) - y sin(pitch) (IMU axes, then ENU)
        right = (cy * r[0] + sy * r[1], cy * r[3] + sy * r[4], cy * r[6] + sy * r[7])
        up = (cp * r[2] - sp * r[1], cp * r[5] - sp * r[4], cp * r[8] - sp * r[7])
        return right, up
