"""Madgwick's gradient-descent attitude filter (Madgwick 2010), MARG and IMU-only.

Madgwick's report writes the Earth frame with gravity on +z and the horizontal magnetic
field on +x. We keep exactly that inside, with +x on *magnetic* north (a north-west-up
frame turned by the declination), so the update is the report's step for step (its eqs.
12, 13, 25-26, 31-34, 45-46: docs/estimator.md#madgwick-update-equations) and the tests
can check it against the `ahrs` package on the same data. Outside, the quaternion is the
project's (docs/frames.md#quaternions): Hamilton, scalar first, rotating body vectors into
ENU, the same `q` as `viena.common.rotation`:

    q_enu = q_off * q_mag,   q_off = rotation about up by 90 deg - declination

Plain floats on purpose: this runs for every IMU sample and numpy's per-call overhead on
4-vectors costs more than the arithmetic.
"""
from __future__ import annotations

import math

from viena.common.rotation import quat_from_euler


class Madgwick:
    """Attitude from gyro + accelerometer (+ magnetometer) by one gradient step per sample.

    `beta` (rad/s) is the gradient step: how fast the accelerometer and magnetometer pull the
    attitude back; too big and linear acceleration tilts it, too small and gyro errors win.
    `declination_rad` is positive east (magnetic north east of true north).
    """

    __slots__ = ("w", "x", "y", "z", "beta", "_ow", "_oz")

    def __init__(self, beta: float = 0.033, declination_rad: float = 0.0, q=(1.0, 0.0, 0.0, 0.0)):
        self.beta = float(beta)
        half = 0.5 * (0.5 * math.pi - declination_rad)
        self._ow, self._oz = math.cos(half), math.sin(half)
        self.w = self.x = self.y = self.z = 0.0
        self.set_quaternion(q)

    # -- state (body -> ENU outside, body -> magnetic NWU inside) -----------------------
    @property
    def q(self) -> tuple[float, float, float, float]:
        """Body -> ENU: q_off * q_mag."""
        c, s = self._ow, self._oz
        w, x, y, z = self.w, self.x, self.y, self.z
        return (c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w)

    def set_quaternion(self, q) -> None:
        """Set from a body -> ENU quaternion (normalised here)."""
        w, x, y, z = (float(v) for v in q)
        n = math.sqrt(w * w + x * x + y * y + z * z)
        if not (n > 0.0 and math.isfinite(n)):
            raise ValueError(f"quaternion {q!r} has no direction")
        w, x, y, z = w / n, x / n, y / n, z / n
        c, s = self._ow, -self._oz                       # q_off conjugate
        self.w, self.x, self.y, self.z = c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w

    def rotate_world_z(self, angle_rad: float) -> None:
        """Turn the attitude about the world up axis (changes yaw only).

        Rotations about up commute with q_off, so the inside quaternion turns the same way.
        """
        c, s = math.cos(0.5 * angle_rad), math.sin(0.5 * angle_rad)
        w, x, y, z = self.w, self.x, self.y, self.z
        self.w, self.x, self.y, self.z = c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w

    def rotate_world(self, ex: float, ny: float, uz: float) -> None:
        """Turn the attitude by the rotation vector (ex, ny, uz), rad, about the world's
        East, North and Up axes: q <- dq * q (a tilt correction from the Kalman filter).

        Inside, the world is magnetic north-west-up, turned from ENU by q_off about up, so
        the vector is turned back by that angle first."""
        c2, s2 = self._ow, self._oz              # cos and sin of half the offset angle
        c, s = c2 * c2 - s2 * s2, 2.0 * c2 * s2  # ... and of the angle
        vx, vy, vz = c * ex + s * ny, -s * ex + c * ny, uz
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        if angle == 0.0:
            return
        h = math.sin(0.5 * angle) / angle
        dw, dx, dy, dz = math.cos(0.5 * angle), vx * h, vy * h, vz * h
        w, x, y, z = self.w, self.x, self.y, self.z
        w, x, y, z = (dw * w - dx * x - dy * y - dz * z, dw * x + dx * w + dy * z - dz * y,
                      dw * y - dx * z + dy * w + dz * x, dw * z + dx * y - dy * x + dz * w)
        n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        self.w, self.x, self.y, self.z = w * n, x * n, y * n, z * n

    # -- updates ------------------------------------------------------------------------
    def update_imu(self, gx, gy, gz, ax, ay, az, dt) -> None:
        """One step from gyro (rad/s) and accelerometer (any unit: it is normalised)."""
        w, x, y, z = self.w, self.x, self.y, self.z
        # rate of change from the gyro: 0.5 q * [0, g]   (eq. 12)
        dw = 0.5 * (-x * gx - y * gy - z * gz)
        dx = 0.5 * (w * gx + y * gz - z * gy)
        dy = 0.5 * (w * gy - x * gz + z * gx)
        dz = 0.5 * (w * gz + x * gy - y * gx)
        an = math.sqrt(ax * ax + ay * ay + az * az)
        if an > 0.0:
            ax, ay, az = ax / an, ay / an, az / an
            # objective: gravity's reaction as q sees it, minus the measurement (eq. 25)
            f0 = 2.0 * (x * z - w * y) - ax
            f1 = 2.0 * (w * x + y * z) - ay
            f2 = 2.0 * (0.5 - x * x - y * y) - az
            # J^T f, J of eq. 26
            sw = -2.0 * y * f0 + 2.0 * x * f1
            sx = 2.0 * z * f0 + 2.0 * w * f1 - 4.0 * x * f2
            sy = -2.0 * w * f0 + 2.0 * z * f1 - 4.0 * y * f2
            sz = 2.0 * x * f0 + 2.0 * y * f1
            dw, dx, dy, dz = self._descend(dw, dx, dy, dz, sw, sx, sy, sz)
        self._integrate(dw, dx, dy, dz, dt)

    def update_marg(self, gx, gy, gz, ax, ay, az, mx, my, mz, dt) -> None:
        """One step from gyro (rad/s), accelerometer and magnetometer (any units)."""
        mn = math.sqrt(mx * mx + my * my + mz * mz)
        an = math.sqrt(ax * ax + ay * ay + az * az)
        if mn == 0.0 or an == 0.0:
            self.update_imu(gx, gy, gz, ax, ay, az, dt)
            return
        w, x, y, z = self.w, self.x, self.y, self.z
        dw = 0.5 * (-x * gx - y * gy - z * gz)
        dx = 0.5 * (w * gx + y * gz - z * gy)
        dy = 0.5 * (w * gy - x * gz + z * gx)
        dz = 0.5 * (w * gz + x * gy - y * gx)
        ax, ay, az = ax / an, ay / an, az / an
        mx, my, mz = mx / mn, my / mn, mz / mn
        # the measured field in the Earth frame, h = q m q* (eq. 45), laid onto +x (eq. 46)
        hx = (1 - 2 * (y * y + z * z)) * mx + 2 * (x * y - w * z) * my + 2 * (x * z + w * y) * mz
        hy = 2 * (x * y + w * z) * mx + (1 - 2 * (x * x + z * z)) * my + 2 * (y * z - w * x) * mz
        hz = 2 * (x * z - w * y) * mx + 2 * (y * z + w * x) * my + (1 - 2 * (x * x + y * y)) * mz
        bx = math.sqrt(hx * hx + hy * hy)
        bz = hz
        # objective (eq. 31)
        f0 = 2.0 * (x * z - w * y) - ax
        f1 = 2.0 * (w * x + y * z) - ay
        f2 = 2.0 * (0.5 - x * x - y * y) - az
        f3 = 2.0 * bx * (0.5 - y * y - z * z) + 2.0 * bz * (x * z - w * y) - mx
        f4 = 2.0 * bx * (x * y - w * z) + 2.0 * bz * (w * x + y * z) - my
        f5 = 2.0 * bx * (w * y + x * z) + 2.0 * bz * (0.5 - x * x - y * y) - mz
        # J^T f, J of eq. 32
        sw = (-2.0 * y * f0 + 2.0 * x * f1 - 2.0 * bz * y * f3
              + (-2.0 * bx * z + 2.0 * bz * x) * f4 + 2.0 * bx * y * f5)
        sx = (2.0 * z * f0 + 2.0 * w * f1 - 4.0 * x * f2 + 2.0 * bz * z * f3
              + (2.0 * bx * y + 2.0 * bz * w) * f4 + (2.0 * bx * z - 4.0 * bz * x) * f5)
        sy = (-2.0 * w * f0 + 2.0 * z * f1 - 4.0 * y * f2 + (-4.0 * bx * y - 2.0 * bz * w) * f3
              + (2.0 * bx * x + 2.0 * bz * z) * f4 + (2.0 * bx * w - 4.0 * bz * y) * f5)
        sz = (2.0 * x * f0 + 2.0 * y * f1 + (-4.0 * bx * z + 2.0 * bz * x) * f3
              + (-2.0 * bx * w + 2.0 * bz * y) * f4 + 2.0 * bx * x * f5)
        dw, dx, dy, dz = self._descend(dw, dx, dy, dz, sw, sx, sy, sz)
        self._integrate(dw, dx, dy, dz, dt)

    # -- internals ----------------------------------------------------------------------
    def _descend(self, dw, dx, dy, dz, sw, sx, sy, sz):
        """Subtract beta times the normalised gradient (eq. 33)."""
        n = math.sqrt(sw * sw + sx * sx + sy * sy + sz * sz)
        if n > 0.0:
            k = self.beta / n
            return dw - k * sw, dx - k * sx, dy - k * sy, dz - k * sz
        return dw, dx, dy, dz

    def _integrate(self, dw, dx, dy, dz, dt) -> None:
        """q + q_dot dt, normalised (eq. 13)."""
        w = self.w + dw * dt
        x = self.x + dx * dt
        y = self.y + dy * dt
        z = self.z + dz * dt
        n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        self.w, self.x, self.y, self.z = w * n, x * n, y * n, z * n


def attitude_from_vectors(accel, mag=None, declination_rad: float = 0.0):
    """Body -> ENU quaternion of a still sensor: roll and pitch from the specific force
    (which points up), yaw from the magnetic field if given (else 0)."""
    fx, fy, fz = (float(v) for v in accel)
    # f = R^T [0, 0, g] = g [-sin(pitch), sin(roll) cos(pitch), cos(roll) cos(pitch)]
    roll = math.atan2(fy, fz)
    pitch = math.atan2(-fx, math.hypot(fy, fz))
    yaw = 0.0
    if mag is not None:
        # the field seen in a frame that is level but still turned by the unknown yaw
        cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
        mx, my, mz = (float(v) for v in mag)
        hx = cp * mx + sp * sr * my + sp * cr * mz
        hy = cr * my - sr * mz
        # its azimuth there is the declination plus the yaw
        yaw = math.atan2(hx, hy) - declination_rad
    return tuple(float(v) for v in quat_from_euler(yaw, pitch, roll))

