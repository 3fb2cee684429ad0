"""Yaw, pitch and roll as a driver means them (viena.estimator.state/2, docs/frames.md).

The body frame is x right, y forward, z up, so the car's angles turn about those axes:
yaw about up, pitch about the right axis (x, nose up positive), roll about the forward
axis (y, right side down positive). The order is the aircraft one, carried over to a
y-forward frame: yaw, then pitch, then roll, intrinsic, so

    R = Rz(yaw) Rx(pitch) Ry(roll)          (Z-X-Y; body -> ENU)

which makes pitch the elevation of the forward axis (the road's grade, atan of it) and
yaw the heading of the forward axis (what the course over ground measures), whatever the
roll. `common/rotation.py`'s Z-Y-X angles with y forward turn first about the forward
axis: same names, other axes, and a different second-order answer when both tilts are
non-zero (docs/frames.md#angles-of-the-estimators-state).
"""
from __future__ import annotations

import math


def yaw_pitch_roll(q) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in rad of a body -> ENU quaternion [w, x, y, z] (normalised).

    From R's third row [-cos(p) sin(r), sin(p), cos(p) cos(r)] and second column
    [-sin(y) cos(p), cos(y) cos(p), sin(p)]; pitch is clipped to +-90 deg."""
    w, x, y, z = q
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (y * z + w * x))))
    roll = math.atan2(-2.0 * (x * z - w * y), 1.0 - 2.0 * (x * x + y * y))
    yaw = math.atan2(-2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z))
    return yaw, pitch, roll


def quat_from_yaw_pitch_roll(yaw: float, pitch: float, roll: float) -> tuple[float, float, float, float]:
    """The body -> ENU quaternion qz(yaw) * qx(pitch) * qy(roll), scalar first."""
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    # qz * qx = (cy cp, cy sp, sy sp, sy cp); then times qy = (cr, 0, sr, 0)
    w, x, y, z = cy * cp, cy * sp, sy * sp, sy * cp
    return (w * cr - y * sr, x * cr - z * sr, w * sr + y * cr, z * cr + x * sr)


def tilt_from_specific_force(fx: float, fy: float, fz: float) -> tuple[float, float]:
    """(pitch, roll) of a still car: its specific force is R^T [0, 0, g] =
    g [-cos(p) sin(r), sin(p), cos(p) cos(r)] in the body."""
    return math.atan2(fy, math.hypot(fx, fz)), math.atan2(-fx, fz)


def forward_yaw(r) -> float:
    """Heading of the forward axis of a body -> ENU rotation (row-major 9-tuple), the
    yaw above: what the course over ground of a car driving forward measures."""
    return math.atan2(-r[1], r[4])


def tilt_about_car(P, rot) -> list[float]:
    """Variance of the Kalman filter's tilt (states 9, 10: about East and North) about the
    car's forward and right axes (rad^2), the attitude being `rot` (body -> ENU, row-major)."""
    # the forward (body y) and right (body x) axes, horizontally, in ENU
    f = (rot[1], rot[4])
    g = (rot[0], rot[3])
    pee, pen, pnn = float(P[9, 9]), float(P[9, 10]), float(P[10, 10])
    return [f[0] * f[0] * pee + 2 * f[0] * f[1] * pen + f[1] * f[1] * pnn,
            g[0] * g[0] * pee + 2 * g[0] * g[1] * pen + g[1] * g[1] * pnn]
