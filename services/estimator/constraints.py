"""What the car's nature says about its velocity: pseudo-measurements for the Kalman filter.

A standing car stands (zero velocity); a moving one neither slides sideways nor leaves the
road (non-holonomic: its body x and z velocity are zero). They ride along with each GNSS
fix while the IMU is live, and run on their own every `constraint_interval_s` when no fix
carried them lately. Equations: docs/estimator.md#pseudo-measurements.
"""
from __future__ import annotations

import numpy as np

from viena.services.estimator.settings import EstimatorSettings


class Constraints:
    def __init__(self, settings: EstimatorSettings, counts: dict, mount):
        self.counts = counts
        self.mount = mount                  # the car's axes in the IMU's (mount.py)
        self.nhc, self.nhc_var = settings.nonholonomic, settings.nhc_sigma_mps ** 2
        self.zupt_R = np.eye(3) * settings.zupt_sigma_mps ** 2
        self.interval_ns = int(settings.constraint_interval_s * 1e9)
        self.next_t = 0                     # when the constraints are due next on their own
        self.last_t = 0                     # when they were last applied (alone or with a fix)

    def rows(self, kf, attitude, heading, still: bool, tilt_right_var: float = 0.0):
        """The pseudo-measurements as (H, innovation, R) rows on the velocity, or None;
        `tilt_right_var` is the attitude's variance about the right axis (rad^2)."""
        ve, vn, vu = kf.x[3], kf.x[4], kf.x[5]
        if still:
            self.counts["zupt"] += 1
            H = np.zeros((3, kf.n))
            H[:, 3:6] = np.eye(3)
            return H, [-ve, -vn, -vu], self.zupt_R
        if not (self.nhc and heading.valid and attitude.aligned):
            return None
        right, up = self.mount.axes(attitude.rot)
        speed2 = ve * ve + vn * vn + vu * vu
        # an attitude error turns the constraint, and so does what is not known of the
        # IMU's mount: widen it by speed x angle sigma
        sig2 = self.nhc_var + speed2 * self.mount.var
        R = np.array(((sig2 + speed2 * heading.yaw_var(), 0.0),
                      (0.0, sig2 + speed2 * tilt_right_var)))
        H = np.zeros((2, kf.n))
        H[0, 3:6] = right                                 # the car's right axis in ENU
        H[1, 3:6] = up                                    # its up axis
        self.counts["nhc"] += 1
        return H, [-(right[0] * ve + right[1] * vn + right[2] * vu), -(up[0] * ve + up[1] * vn + up[2] * vu)], R
