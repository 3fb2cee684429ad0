"""Rotations as the whole project writes them (docs/frames.md#rotation-matrices-and-euler-angles).

Euler angles are Tait-Bryan intrinsic Z-Y-X (yaw psi, pitch theta, roll phi):
R = Rz(psi) Ry(theta) Rx(phi) rotates body vectors into the world (ENU).
Quaternions are Hamilton, scalar first, [q1 q2 q3 q4] = [w x y z], same meaning as R.
"""
from __future__ import annotations

import math

import numpy as np


def unit_quat(q) -> list[float] | np.ndarray:
    """q / |q| as Python floats, the norm being np.linalg.norm's own sqrt(q . q) (same bits)
    without its checks: the simulated car asks for this ~100 times a simulated second, and
    arithmetic on Python floats is several times cheaper than on numpy scalars (IEEE division
    is exact, so dividing the floats gives numpy's bits)."""
    a = np.asarray(q)
    if a.ndim != 1 or a.dtype != np.float64:
        return np.asarray(q, float) / np.linalg.norm(q)     # anything else, as it always was
    a = np.ascontiguousarray(a)                             # as norm's ravel
    norm = math.sqrt(a.dot(a))
    if norm == 0.0:
        return (a / norm).tolist()                          # numpy's nans (and warning), not an exception
    return [v / norm for v in a.tolist()]


def quat_to_matrix(q) -> np.ndarray:
    return unit_quat_to_matrix(*unit_quat(q))


def unit_quat_to_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of a quaternion already of unit length."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_euler(yaw: float, pitch: float, roll: float) -> np.ndarray:
    return np.array(quat_floats_from_euler(yaw, pitch, roll))


def quat_floats_from_euler(yaw: float, pitch: float, roll: float) -> tuple[float, float, float, float]:
    """quat_from_euler as a tuple of Python floats."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in rad; pitch is clipped to +-90 deg at the singularity."""
    return euler_from_unit_quat(*unit_quat(q))


def euler_from_unit_quat(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """euler_from_quat of a quaternion already of unit length."""
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return yaw, pitch, roll


def euler_to_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), body to ENU (docs/frames.md#rotation-matrices-and-euler-angles)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a * b."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def wrap_angle(a: float) -> float:
    """Wrap to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi
