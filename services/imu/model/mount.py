"""How the IMU board sits in the car: the rotation from board axes to body axes, and how
to measure it from a recording.

A board screwed into a car is rarely square to it: an axis swap (the board turned 90 deg,
or upside down) plus a few degrees of tilt and yaw is normal. The service applies the
unit's mount to every sample, so what it publishes is in the body frame (x right,
y forward, z up) while the `raw` values stay as the board sent them.

The mount is written as three angles, `zyx_deg = [z, y, x]`: R = Rz(z) Ry(y) Rx(x), turns
about the body's up, forward and right axes in that order, with v_body = R v_board
(docs/sensors.md#mount-board-to-body). [0, 0, 0] is a board square to the car.

Measuring it (`viena calibrate imu mount`), from calibrated board-frame samples and the
fixes of a GNSS receiver on the same drive:
1. roll and pitch from gravity while parked: the mean specific force is straight up in
   the body, so the rotation taking it to +z levels the board (the car must be parked on
   level ground: a 2 % slope is a 1.1 deg error);
2. yaw from driving: in the levelled board frame the horizontal specific force is the
   car's (lateral, forward) acceleration turned by the unknown yaw; the GNSS gives that
   acceleration (speed change forward, speed x yaw rate sideways), and the yaw is the
   2-D rotation that best maps one onto the other (least squares).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.common.rotation import euler_to_matrix
from viena.services.imu.model.motion import GnssMotion, moving_average

#: parked means no motion this long before and after (a car starting off tilts the level)
PARKED_MARGIN_S = 1.0
PARKED_GYRO_RADPS = 0.02
#: acceleration worth fitting the yaw to (m/s^2, horizontal)
MIN_HORIZONTAL_MPS2 = 0.3


@dataclass(frozen=True)
class Mount:
    """Board to body rotation as Z-Y-X angles in degrees (see the module docstring)."""

    zyx_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def matrix(self) -> np.ndarray:
        z, y, x = (math.radians(a) for a in self.zyx_deg)
        return euler_to_matrix(z, y, x)

    @property
    def is_identity(self) -> bool:
        return all(a == 0.0 for a in self.zyx_deg)

    @classmethod
    def of_matrix(cls, r: np.ndarray) -> Mount:
        y = math.asin(max(-1.0, min(1.0, -float(r[2, 0]))))
        z = math.atan2(float(r[1, 0]), float(r[0, 0]))
        x = math.atan2(float(r[2, 1]), float(r[2, 2]))
        return cls(tuple(round(math.degrees(a), 4) for a in (z, y, x)))

    def angle_to_deg(self, other: Mount) -> float:
        """The angle of the rotation between two mounts: how far apart they are."""
        rel = self.matrix.T @ other.matrix
        return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2))))


@dataclass(frozen=True)
class MountEstimate:
    mount: Mount
    parked_samples: int
    moving_samples: int
    yaw_residual_mps2: float          # RMS misfit of the horizontal accelerations
    yaw_sigma_deg: float              # from the misfit and how much the car accelerated


def levelling(gravity_board: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the measured 'up' (mean specific force at rest) to +z."""
    up = np.asarray(gravity_board, float) / np.linalg.norm(gravity_board)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])       # upside down: turn about x
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def estimate_mount(t_s: np.ndarray, accel_board: np.ndarray, gyro_board: np.ndarray,
                   motion: GnssMotion, smooth_s: float = 1.0) -> MountEstimate:
    """The mount from board-frame specific force and rates (SI) at times t_s, and the GNSS
    motion of the same drive (on the same clock: measure the time offset first if the IMU's
    clock may be off by more than a few tens of ms)."""
    t_s = np.asarray(t_s, float)
    accel, gyro = np.asarray(accel_board, float), np.asarray(gyro_board, float)
    parked = (np.interp(t_s, motion.t_s, motion.parked(PARKED_MARGIN_S).astype(float)) > 0.99) \
        & (np.linalg.norm(gyro, axis=1) < PARKED_GYRO_RADPS)
    if parked.sum() < 100:
        raise ValueError(f"only {parked.sum()} samples parked: the recording must start with the car "
                         f"standing still on level ground for a few seconds")
    level = levelling(accel[parked].mean(axis=0))
    horizontal = moving_average(t_s, accel @ level.T, smooth_s)[:, :2]

    moving = np.interp(t_s, motion.t_s, motion.moving.astype(float)) > 0.99
    # the GNSS side smoothed alike: a car's accelerations last seconds, the noise does not
    expected = moving_average(t_s, np.column_stack([
        np.interp(t_s, motion.t_s, motion.lateral_accel_mps2()),
        np.interp(t_s, motion.t_s, motion.forward_accel_mps2)]), smooth_s)
    use = moving & (np.linalg.norm(expected, axis=1) > MIN_HORIZONTAL_MPS2)
    if use.sum() < 100:
        raise ValueError(f"only {use.sum()} samples of the car accelerating or turning: drive a few "
                         f"turns and speed changes above {MIN_HORIZONTAL_MPS2} m/s^2")
    h, e = horizontal[use], expected[use]
    yaw = math.atan2(float(np.sum(h[:, 0] * e[:, 1] - h[:, 1] * e[:, 0])),
                     float(np.sum(h[:, 0] * e[:, 0] + h[:, 1] * e[:, 1])))
    turn = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    residual = e - h @ turn[:2, :2].T
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    # the samples are correlated over the smoothing window: count independent ones
    independent = max(1.0, use.sum() * float(np.median(np.diff(t_s))) / smooth_s)
    sigma = math.degrees(rms / (float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) * math.sqrt(independent)))
    return MountEstimate(Mount.of_matrix(turn @ level), int(parked.sum()), int(use.sum()), rms, sigma)
