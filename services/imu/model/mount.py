"""How the IMU board sits in the car: the rotation from board axes to body axes, and how
to measure it from a recording.

A board screwed into a car is rarely square to it: an axis swap (the board turned 90 deg,
or upside down) plus a few degrees of tilt and yaw is normal. The service applies the
unit's mount to every sample, so what it publishes is in the body frame (x right,
y forward, z up) while the `raw` values stay as the board sent them.

The mount is written as three angles, `zyx_deg = [z, y, x]`: R = Rz(z) Ry(y) Rx(x), turns
about the body's up, forward and right axes in that order, with v_body = R v_board
(docs/sensors.md#mount-board-to-body). [0, 0, 0] is a board square to the car.

Measuring it (`viena calibrate imu mount`), from calibrated board-frame samples timed to
the GNSS clock (model/time_offset.py) and the fixes of a receiver on the same drive: over
every interval of a second while driving (one starting at each fix), the GNSS gives the
velocity change plus gravity in the body axes (heading from the course, pitch from the
path's climb: model/motion.py) and the IMU the specific force it integrated, in its axes,
turned along about the vertical as the board sees it on that slope. The mount is the
rotation taking the one onto the other in least squares (Wahba's problem, by SVD): gravity
sets the tilt; the yaw is fitted again on the horizontal parts less their means, so that
a constant offset (the accelerometer's bias, a slope misjudged) cannot turn it on a drive
whose turns go mostly one way. The road's slope is in the GNSS's climb, so hills and a
stop on a slope do not tilt the mount; its bank is not, and is taken as level on average.
Parked stops are not used for the level, except two at one place facing opposite ways:
their mean up is the car's whatever the slope and bank. Each stop's slope is reported.
The uncertainty is a block bootstrap over 10 s stretches of driving, plus what no drive
shows: the accelerometer's bias and misalignment (ACCEL_BIAS_G, ACCEL_MISALIGNMENT_RAD).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from viena.common.rotation import euler_to_matrix
from viena.services.imu.model.fitting import block_weights, bootstrap_sigma
from viena.services.imu.model.motion import GnssMotion, ImuTrack, at_rest

#: parked means no motion this long before and after (a car starting off tilts the level)
PARKED_MARGIN_S = 1.0
PARKED_GYRO_RADPS = 0.02
#: a stop worth its mean: this long standing still
MIN_STOP_S = 3.0
#: two stops facing opposite ways count as one place within this distance and angle
SAME_PLACE_M = 5.0
OPPOSITE_WITHIN_DEG = 30.0
#: what two stops at one place leave of the level: the ground is not the same under both
STOP_PAIR_SIGMA_DEG = 0.1
#: what no drive can tell from the mount, added to the bootstrap's spread: the bias an
#: accelerometer keeps after its six-position calibration tilts the level it reads
#: (3 mg: 0.17 deg), and its axes' misalignment, which that fit leaves out, tilts and
#: turns it (3 mrad: 0.17 deg); the Razor twin's assumptions (docs/sensors.md#imu-error-model)
ACCEL_BIAS_G = 0.003
ACCEL_MISALIGNMENT_RAD = 0.003
#: acceleration worth fitting the yaw to (m/s^2, horizontal)
MIN_HORIZONTAL_MPS2 = 0.3
MIN_ACCELERATING_S = 10.0
BLOCK_S = 10.0
MOUNT_SPAN_S = 1.0
PITCH_STEP_DEG = 0.25
MOUNT_EVERY_S = 0.0               # every fix starts one: each fix adds its own noise, to average


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
        return cls((round(math.degrees(z), 4), round(math.degrees(y), 4), round(math.degrees(x), 4)))

    def angle_to_deg(self, other: Mount) -> float:
        """The angle of the rotation between two mounts: how far apart they are."""
        rel = self.matrix.T @ other.matrix
        return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2))))


@dataclass(frozen=True)
class Stop:
    """A stretch parked: where, facing where, and the slope it stands on by the mount found."""

    start_s: float
    end_s: float
    samples: int
    up_board: np.ndarray           # gravity's reaction, board axes (unit)
    gyro_mean: np.ndarray          # the gyro's bias
    place_enu_m: np.ndarray
    heading_rad: float
    nose_up_deg: float = math.nan
    right_up_deg: float = math.nan

    @property
    def slope_deg(self) -> float:
        return math.degrees(math.acos(min(1.0, math.cos(math.radians(self.nose_up_deg))
                                          * math.cos(math.radians(self.right_up_deg)))))

    def __str__(self) -> str:
        return (f"parked {self.start_s:.0f}-{self.end_s:.0f} s: slope {self.slope_deg:.1f} deg "
                f"(nose up {self.nose_up_deg:+.1f}, right side up {self.right_up_deg:+.1f})")


@dataclass(frozen=True)
class MountEstimate:
    mount: Mount
    sigma_deg: float                  # of the whole rotation: tilt and yaw together
    tilt_sigma_deg: float
    yaw_sigma_deg: float
    residual_mps: float               # RMS misfit of an interval's velocity change
    driving_s: float
    level: str                        # what set the tilt: "driving" or "stops facing both ways"
    stops: tuple[Stop, ...] = field(default_factory=tuple)

    @property
    def parked_samples(self) -> int:
        return sum(s.samples for s in self.stops)


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


def wahba(b: np.ndarray) -> np.ndarray:
    """The rotations R maximising trace(R^T B) for B = sum y u^T (... x 3 x 3): the best
    R taking each u onto its y in least squares (Markley's SVD solution)."""
    u, _, vt = np.linalg.svd(b)
    d = np.linalg.det(u) * np.linalg.det(vt)
    fix = np.ones(u.shape[:-1])
    fix[..., 2] = d
    return (u * fix[..., None, :]) @ vt


def estimate_mount(t_s: np.ndarray, accel_board: np.ndarray, gyro_board: np.ndarray,
                   motion: GnssMotion) -> MountEstimate:
    """The mount from board-frame specific force and rates (SI) at times t_s on the GNSS's
    clock (time the IMU first: model/time_offset.py), and the GNSS motion of the drive."""
    t_s = np.asarray(t_s, float)
    accel, gyro = np.asarray(accel_board, float), np.asarray(gyro_board, float)
    stops = find_stops(t_s, accel, gyro, motion)
    y, u, a, driving_s = _driving(t_s, accel, gyro, motion)
    rot = _fit(y, u, np.ones((1, len(y))))[0]
    residual = float(np.sqrt(np.mean(np.sum((y - u @ rot.T) ** 2, axis=1))))
    tilt_sigma, yaw_sigma = _uncertainty(y, u, a, rot)
    level = "driving"
    pair = facing_both_ways(stops)
    if pair is not None:
        rot = levelling(rot @ pair[0].up_board + rot @ pair[1].up_board) @ rot
        tilt_sigma = float(math.sqrt(STOP_PAIR_SIGMA_DEG ** 2 + 2 * _unseen_tilt_deg() ** 2))
        level = "stops facing both ways"
    return MountEstimate(Mount.of_matrix(rot), float(math.hypot(tilt_sigma, yaw_sigma)), tilt_sigma, yaw_sigma,
                         residual, driving_s, level, tuple(_with_slope(s, rot) for s in stops))


def _driving(t_s, accel, gyro, motion: GnssMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(GNSS increments y, IMU increments u, interval starts, seconds of driving) over
    intervals of MOUNT_SPAN_S while moving; refused without enough accelerating."""
    i, j = motion.intervals(MOUNT_SPAN_S, every_s=MOUNT_EVERY_S)
    inside = (motion.t_s[i] >= t_s[0]) & (motion.t_s[j] <= t_s[-1])
    i, j = i[inside], j[inside]
    a, b = motion.t_s[i], motion.t_s[j]
    v = motion.velocity_enu()[:, :2]
    spacing = max(motion.fix_interval_s, MOUNT_EVERY_S)          # seconds of driving an interval stands for
    accelerating = float(np.sum(np.linalg.norm(v[j] - v[i], axis=1) / np.maximum(b - a, 1e-9)
                                > MIN_HORIZONTAL_MPS2) * spacing)
    if accelerating < MIN_ACCELERATING_S:
        raise ValueError(f"{accelerating:.0f} s of the car accelerating or turning: drive turns and speed "
                         f"changes above {MIN_HORIZONTAL_MPS2} m/s^2 for at least {MIN_ACCELERATING_S:.0f} s")
    y = motion.body_increments(i, j)
    # the IMU turned about the board's up first, then about the vertical on the road's slope
    # as the mount found so far has it (twice: the axis hardly moves the mount)
    rest = at_rest(t_s, accel, gyro, motion, 0.0, PARKED_MARGIN_S)
    u = ImuTrack(t_s, accel, gyro, rest.up, rest.gyro_bias).increments(a, b)
    for _ in range(2):
        u = _turned_about_vertical(t_s, accel, gyro, rest.gyro_bias, _fit(y, u, np.ones((1, len(y))))[0],
                                   motion.climb_rad[i], a, b)
    return y, u, a, float(len(i) * spacing)


def _uncertainty(y: np.ndarray, u: np.ndarray, a: np.ndarray, rot: np.ndarray) -> tuple[float, float]:
    """(tilt, yaw) sigmas in degrees: the spread of the fit over a block bootstrap of the
    drive, and what no drive shows (ACCEL_BIAS_G, ACCEL_MISALIGNMENT_RAD)."""
    (draw,), blocks = block_weights([a], BLOCK_S)
    turn = _fit(y, u, draw) @ rot.T                           # small rotations about body axes
    delta = np.degrees(np.stack([turn[:, 2, 1] - turn[:, 1, 2], turn[:, 0, 2] - turn[:, 2, 0],
                                 turn[:, 1, 0] - turn[:, 0, 1]], -1) / 2)
    spread = bootstrap_sigma(delta, blocks)
    tilt = float(np.sqrt(spread[0] ** 2 + spread[1] ** 2 + 2 * _unseen_tilt_deg() ** 2))
    # the yaw rests on the sideways axis in turns, the forward one in speed changes: each
    # turned by its own misalignment, not by their mean
    yaw = float(math.hypot(spread[2], math.degrees(ACCEL_MISALIGNMENT_RAD)))
    return tilt, yaw


def _unseen_tilt_deg() -> float:
    """Per tilt axis: the accelerometer's bias and its up axis's misalignment."""
    return math.degrees(math.hypot(ACCEL_BIAS_G, ACCEL_MISALIGNMENT_RAD))


def _turned_about_vertical(t_s, accel, gyro, gyro_bias, mount: np.ndarray, pitch: np.ndarray,
                           a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The IMU's increments from a to b, turned along about the vertical as the board sees
    it on a road of the given pitch: a car on a slope turns about the vertical, not about
    its own up, and a turn about its own up would lean the slope's share of gravity
    sideways (at 8 %, a tenth of the centripetal acceleration). Pitches are taken in
    steps of PITCH_STEP_DEG, one track per step."""
    step = math.radians(PITCH_STEP_DEG)
    bins = np.round(pitch / step).astype(int)
    u = np.empty((len(a), 3))
    for k in np.unique(bins):
        sel = bins == k
        vertical = mount.T @ np.array([0.0, math.sin(k * step), math.cos(k * step)])
        u[sel] = ImuTrack(t_s, accel, gyro, vertical, gyro_bias).increments(a[sel], b[sel])
    return u


def _fit(y: np.ndarray, u: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Mounts (one per row of weights) taking the IMU's increments u onto the GNSS's y:
    the whole vectors for the level (gravity outweighs all else), then the yaw again from
    the horizontal parts less their means. A constant horizontal offset (the
    accelerometer's bias, the mean of a slope the GNSS misjudges) would otherwise turn
    the yaw on a drive whose turns go mostly one way: the offset leans on the mean
    sideways acceleration like a turned board."""
    total = weights.sum(axis=1)[:, None]
    level = wahba(np.einsum("rk,ki,kj->rij", weights, y, u))
    v = np.einsum("rij,kj->rki", level, u)[..., :2]                          # r x k x 2
    h = y[:, :2]
    h_mean = weights @ h / total                                              # r x 2
    v_mean = np.einsum("rk,rki->ri", weights, v) / total
    cross = np.einsum("rk,ki,rkj->rij", weights, h, v) - total[:, :, None] * h_mean[:, :, None] * v_mean[:, None, :]
    yaw = np.arctan2(cross[:, 1, 0] - cross[:, 0, 1], cross[:, 0, 0] + cross[:, 1, 1])
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    turn = np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)
    return turn @ level


def find_stops(t_s: np.ndarray, accel: np.ndarray, gyro: np.ndarray, motion: GnssMotion) -> list[Stop]:
    """The drive's stops of at least MIN_STOP_S: parked by the GNSS (with a margin either
    side) and still by the gyro."""
    parked = np.interp(t_s, motion.t_s, motion.parked(PARKED_MARGIN_S).astype(float)) > 0.99
    if parked.any():
        parked &= np.linalg.norm(gyro - np.median(gyro[parked], axis=0), axis=1) < PARKED_GYRO_RADPS
    edges = np.flatnonzero(np.diff(np.concatenate([[0], parked.astype(int), [0]])))
    stops = []
    for start, end in zip(edges[::2], edges[1::2]):
        if t_s[end - 1] - t_s[start] < MIN_STOP_S:
            continue
        up = accel[start:end].mean(axis=0)
        at = (motion.t_s >= t_s[start]) & (motion.t_s <= t_s[end - 1])
        near = int(np.argmin(np.abs(motion.t_s - t_s[start])))
        place = motion.enu_m[at].mean(axis=0) if at.any() else motion.enu_m[near]
        stops.append(Stop(float(t_s[start] - t_s[0]), float(t_s[end - 1] - t_s[0]), int(end - start),
                          up / np.linalg.norm(up), gyro[start:end].mean(axis=0), place, float(motion.yaw_rad[near])))
    return stops


def facing_both_ways(stops: list[Stop]) -> tuple[Stop, Stop] | None:
    """Two stops at one place facing opposite ways (the longest such pair): the slope
    under them tilts the car one way, then the other, and their mean is level."""
    best, length = None, 0
    for k, first in enumerate(stops):
        for second in stops[k + 1:]:
            apart = float(np.linalg.norm((first.place_enu_m - second.place_enu_m)[:2]))
            turned = abs(math.remainder(first.heading_rad - second.heading_rad - math.pi, 2 * math.pi))
            if apart < SAME_PLACE_M and math.degrees(turned) < OPPOSITE_WITHIN_DEG:
                if min(first.samples, second.samples) > length:
                    best, length = (first, second), min(first.samples, second.samples)
    return best


def _with_slope(stop: Stop, rot: np.ndarray) -> Stop:
    up = rot @ stop.up_board
    return Stop(stop.start_s, stop.end_s, stop.samples, stop.up_board, stop.gyro_mean, stop.place_enu_m,
                stop.heading_rad,
                math.degrees(math.asin(max(-1.0, min(1.0, float(up[1]))))),
                math.degrees(math.asin(max(-1.0, min(1.0, float(up[0]))))))
