"""The car's motion over one interval as the GNSS sees it and as the IMU integrates it: what
`viena calibrate imu mount|time` compare.

GNSS side (`gnss_motion`): from the fixes' velocities (Doppler velocity is smooth where
positions are not; a receiver that sends positions only gets velocities by central
differences of its positions): speed, the yaw the course implies, the climb of the path,
each on the receiver's own clock corrected by the velocity's reported latency. Body frame
x right, y forward, z up; yaw 0 points north and grows counter-clockwise (docs/frames.md).

The car points where it goes only at the point that does not slip sideways, the rear
axle, which is the body origin. An antenna a metre ahead of it moves sideways in a turn
(velocity = v_origin + omega x lever arm), so its course leads the heading by
asin(lever_y omega / v): at 4 m/s that looks like a quarter of a second. The antenna's
lever arm takes this out, so the motion is the body origin's; the turn rate omega is the
IMU's when it is known (any fix rate), else the fixes' own.

Over an interval between two fixes, the GNSS gives the velocity change plus gravity, in
the body axes at the interval's start (`GnssMotion.body_increments`); the IMU gives the
specific force it integrated over the same interval, in its own axes at the start, turned
along about the vertical by its gyro (`ImuTrack.increments`). The two differ by the mount,
whatever the fix rate: nothing is differentiated, and both sides cover the same stretch
of time (the fixes' own turn rates and accelerations, for reports, are differences over
at least one fix either side).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.common.errors import SampleError
from viena.common.geodesy import LocalFrame
from viena.common.samples.fix import read_fix

#: below this speed the course says nothing about where the car points
MOVING_MPS = 2.0
#: a receiver's Doppler velocity, averaged over a second, stays below this when the car stands still
PARKED_MPS = 0.1
#: below this speed a Doppler course is mostly noise: the heading is held
SLOW_MPS = 0.5
#: the interval the GNSS and the IMU are compared over: long enough for the car's velocity
#: to change by more than the fixes' noise, short enough to hold a few per turn
SPAN_S = 1.0
#: a fix further than this from the last is a gap in the track: no interval spans it
MAX_GAP_S = 2.5
#: the road's slope is the climb smoothed over this long: a fix's own vertical velocity is
#: noisy (0.05 m/s is 0.7 deg of pitch at 4 m/s, and a pitch error puts g sin of it into
#: the forward acceleration), a road's slope changes over tens of metres
CLIMB_SMOOTH_S = 10.0


@dataclass(frozen=True)
class GnssMotion:
    """Arrays on one time axis, t_s (seconds on the UTC clock of the fixes)."""

    t_s: np.ndarray
    speed_mps: np.ndarray          # horizontal, of the body origin
    yaw_rad: np.ndarray            # unwrapped, from the course; held when slow
    yaw_rate_radps: np.ndarray     # central differences over at least one fix each side
    forward_accel_mps2: np.ndarray
    climb_rad: np.ndarray          # the path's slope: the car's pitch on the road (0 when slow)
    vel_up_mps: np.ndarray
    enu_m: np.ndarray              # the antenna's positions, from the first fix
    antenna_vel_enu_mps: np.ndarray | None = None    # as the receiver sent it
    gravity_mps2: float = 9.80665
    from_positions: bool = False   # the receiver sent no velocity: differences of positions
    climb_from_heights: bool = False   # nor a vertical one: the climb is from the heights

    @property
    def moving(self) -> np.ndarray:
        return self.speed_mps > MOVING_MPS

    @property
    def fix_interval_s(self) -> float:
        return float(np.median(np.diff(self.t_s))) if len(self.t_s) > 1 else math.nan

    def parked(self, margin_s: float) -> np.ndarray:
        """Standing still, and for margin_s before and after: the antenna's velocity
        averaged over a second (a fix's own noise, 0.03-0.1 m/s, averages out of the
        vector, not out of its length) below PARKED_MPS."""
        vel = self.antenna_vel_enu_mps if self.antenna_vel_enu_mps is not None else self.velocity_enu()
        slow = np.linalg.norm(moving_average(self.t_s, vel[:, :2], 1.0), axis=1) < PARKED_MPS
        start = np.searchsorted(self.t_s, self.t_s - margin_s, side="left")
        end = np.searchsorted(self.t_s, self.t_s + margin_s, side="right")
        fast_before = np.concatenate([[0], np.cumsum(~slow)])
        return (fast_before[end] - fast_before[start]) == 0

    def lateral_accel_mps2(self) -> np.ndarray:
        """What the accelerometer's x axis (right) feels in a turn: the centripetal
        acceleration points left (-x) in a left turn (positive yaw rate)."""
        return -self.speed_mps * self.yaw_rate_radps

    def moving_seconds(self, start_s: float = -math.inf, end_s: float = math.inf) -> float:
        """How long the car drove above walking pace between two times (gaps left out)."""
        t, moving = self.t_s, self.moving
        dt = np.diff(t)
        both = moving[1:] & moving[:-1] & (dt <= MAX_GAP_S) & (t[:-1] >= start_s) & (t[1:] <= end_s)
        return float(dt[both].sum())

    def intervals(self, span_s: float = SPAN_S, every_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) fix indices of intervals about span_s long (at least one fix apart),
        starting every `every_s` (default a quarter span), moving at both ends, no gap inside."""
        t = self.t_s
        n = len(t)
        spacing = self.fix_interval_s if n > 1 else 1.0
        step = max(1, int(round(span_s / spacing)))
        every = max(1, int(round((span_s / 4 if every_s is None else every_s) / spacing)))
        start = np.arange(0, max(n - step, 0), every)
        end = start + step
        gaps = np.concatenate([[0], np.cumsum(np.diff(t) > MAX_GAP_S)])
        ok = self.moving[start] & self.moving[end] & (gaps[end] == gaps[start])
        return start[ok], end[ok]

    def attitude(self, i: np.ndarray) -> np.ndarray:
        """Body to ENU rotations at fixes i (k x 3 x 3): the yaw of the course and the pitch
        of the path; the road's bank is not seen by a GNSS and is taken as level."""
        yaw, pitch = self.yaw_rad[i], self.climb_rad[i]
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        zero, one = np.zeros_like(yaw), np.ones_like(yaw)
        rz = np.stack([np.stack([cy, -sy, zero], -1), np.stack([sy, cy, zero], -1),
                       np.stack([zero, zero, one], -1)], -2)
        rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cp, -sp], -1),
                       np.stack([zero, sp, cp], -1)], -2)
        return rz @ rx

    def velocity_enu(self) -> np.ndarray:
        """The body origin's velocity (n x 3): along its heading, and climbing as the fixes say."""
        return np.column_stack([-self.speed_mps * np.sin(self.yaw_rad), self.speed_mps * np.cos(self.yaw_rad),
                                self.vel_up_mps])

    def body_increments(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """What an accelerometer at the body origin integrates from fix i to fix j, in the
        body axes at fix i (k x 3): the velocity change plus gravity's reaction, g dt up."""
        v = self.velocity_enu()
        dv = v[j] - v[i]
        dv[:, 2] += self.gravity_mps2 * (self.t_s[j] - self.t_s[i])
        return np.einsum("kji,kj->ki", self.attitude(i), dv)


def gnss_motion(fixes: list[dict], lever_arm_m=(0.0, 0.0, 0.0), smooth_s: float = 0.3,
                turn_rate=None) -> GnssMotion:
    """Motion of the body origin from valid fixes (viena.gnss.fix/1 dicts) of an antenna at
    `lever_arm_m` (body frame, from the origin). `turn_rate(t_s)`: the car's yaw rate at
    the fixes' times (rad/s, from the IMU once it is timed), for the lever arm's slip; else
    the fixes' own course changes, solved implicitly.

    Derivatives are central differences over `smooth_s`, and at least one fix either side."""
    rows = []
    for sample in fixes:
        try:
            fix = read_fix(sample)
        except SampleError:
            continue
        if fix.usable:
            rows.append(fix)
    with_velocity = [f for f in rows if f.has_velocity]
    from_positions = len(with_velocity) < max(10, len(rows) // 2)
    if not from_positions:
        rows = with_velocity
    if len(rows) < 10:
        raise ValueError(f"{len(rows)} usable fixes: need a drive of at least a few seconds")
    frame = LocalFrame.at_ecef(rows[0].ecef_m)
    rows.sort(key=lambda f: f.t)
    enu = (np.array([f.ecef_m for f in rows], float) - np.array(rows[0].ecef_m, float)) @ frame.rot_ecef_to_enu.T
    if from_positions:
        t = np.array([f.t * 1e-9 for f in rows])
        vel = np.column_stack([_central(t, enu[:, k]) for k in range(3)])
    else:
        t = np.array([f.t * 1e-9 - f.vel_latency_s for f in rows])
        vel = np.array([f.vel_ecef_mps for f in rows], float) @ frame.rot_ecef_to_enu.T
    keep = np.concatenate([[True], np.diff(t) > 0])             # one fix per epoch
    t, vel, enu = t[keep], vel[keep], enu[keep]
    ant_speed = np.hypot(vel[:, 0], vel[:, 1])
    climb_from_heights = not from_positions and not np.any(vel[:, 2])    # NMEA: no vertical velocity
    vel_up = _derivative(t, enu[:, 2], 2.0) if climb_from_heights else vel[:, 2]
    fast = ant_speed > SLOW_MPS
    climb = np.zeros_like(ant_speed)
    if fast.any():
        climb[fast] = np.arctan2(_twiced(t[fast], vel_up[fast], CLIMB_SMOOTH_S),
                                 _twiced(t[fast], ant_speed[fast], CLIMB_SMOOTH_S))
    course = np.unwrap(np.arctan2(-vel[:, 0], vel[:, 1]))
    # the antenna's lead over the axle in the horizontal: a roof antenna leans back uphill
    arm_x = float(lever_arm_m[0])
    arm_y = float(lever_arm_m[1]) * np.cos(climb) - float(lever_arm_m[2]) * np.sin(climb)
    if turn_rate is not None:
        rate = np.where(ant_speed < SLOW_MPS, 0.0, np.asarray(turn_rate(t), float))
        yaw = _yaw_of_turn(course, ant_speed, rate, arm_y)
    else:
        yaw = _yaw_of_course(t, course, ant_speed, arm_x, arm_y)
        rate = np.where(ant_speed < SLOW_MPS, 0.0, _derivative(t, yaw, smooth_s))
    speed = np.maximum(ant_speed ** 2 - (rate * arm_y) ** 2, 0.0) ** 0.5 - rate * arm_x
    return GnssMotion(t, speed, yaw, rate, _derivative(t, speed, smooth_s), climb, vel_up, enu, vel,
                      frame.gravity_mps2, from_positions, climb_from_heights)


def _twiced(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """A moving average with its own bias taken out (Tukey's twicing, 2 M x - M M x): the
    noise goes as with the average, a hill's slope is kept to within (1 - a)^2 where the
    average alone keeps a of it."""
    once = moving_average(t, x, window_s)
    return 2.0 * once - moving_average(t, once, window_s)


def _yaw_of_turn(course: np.ndarray, ant_speed: np.ndarray, rate: np.ndarray, arm_y: np.ndarray) -> np.ndarray:
    """The heading when the turn rate is known: course = yaw + asin(rate arm_y / antenna speed)."""
    slow = ant_speed < SLOW_MPS
    slip = np.arcsin(np.clip(rate * arm_y / np.maximum(ant_speed, SLOW_MPS), -1.0, 1.0))
    return _held_when_slow(np.where(slow, course, course - slip), slow)


def _yaw_of_course(t: np.ndarray, course: np.ndarray, ant_speed: np.ndarray,
                   arm_x: float, arm_y: np.ndarray) -> np.ndarray:
    """The heading whose turn makes the antenna's course: course = yaw + slip, with
    slip = atan2(rate arm_y, v + rate arm_x) and rate = d yaw / dt. Solved step by step
    (implicitly, by Newton's method), so no derivative of a derivative amplifies noise."""
    slow = ant_speed < SLOW_MPS
    yaw = course.copy()
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        ay = float(arm_y[k])
        if slow[k] or slow[k - 1] or dt <= 0 or ay == 0.0:
            continue                 # standing, or starting again: the course as it is
        y = yaw[k - 1] + (course[k] - course[k - 1])
        for _ in range(4):
            rate = (y - yaw[k - 1]) / dt
            forward = ant_speed[k] + rate * arm_x
            slip = math.atan2(rate * ay, forward)
            d_slip = (ay * forward - rate * ay * arm_x) / (forward ** 2 + (rate * ay) ** 2) / dt
            y -= (y + slip - course[k]) / (1.0 + d_slip)
        yaw[k] = y
    return _held_when_slow(yaw, slow)


def _held_when_slow(yaw: np.ndarray, slow: np.ndarray) -> np.ndarray:
    """Standing still the car does not turn: the heading it had (or will have) moving."""
    moving = np.flatnonzero(~slow)
    if len(moving):
        index = np.arange(len(yaw))
        nearest = moving[np.clip(np.searchsorted(moving, index, side="right") - 1, 0, None)]
        nearest = np.where(index < moving[0], moving[0], nearest)
        yaw = np.where(slow, yaw[nearest], yaw)
    return yaw


def _derivative(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """d x / d t by central differences over window_s, and over at least one neighbour each
    side (edges: one-sided). Fixes further apart than half the window would otherwise
    find no neighbour inside it, and every derivative would come out zero."""
    n = len(t)
    index = np.arange(n)
    before = np.minimum(np.searchsorted(t, t - window_s / 2, side="right") - 1, index - 1).clip(0, n - 1)
    after = np.maximum(np.searchsorted(t, t + window_s / 2, side="left"), index + 1).clip(0, n - 1)
    dt = t[after] - t[before]
    out = np.zeros_like(x, dtype=float)
    ok = dt > 0
    out[ok] = (x[after] - x[before])[ok] / dt[ok]
    return out


def _central(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Velocity from positions: the neighbours' difference, at each fix's own time."""
    return _derivative(t, x, 0.0)


@dataclass(frozen=True)
class Rest:
    """Where the IMU stood still, and what it read there: gravity's reaction gives its up
    axis, the mean rate its gyro's bias."""

    still: np.ndarray              # per sample
    up: np.ndarray                 # unit vector in the IMU's axes
    gyro_bias: np.ndarray
    still_s: float
    how: str                       # "parked", "steady" or "mean of the drive"


def at_rest(t_s, accel, gyro, motion: GnssMotion | None = None, offset_s: float = 0.0,
            margin_s: float = 1.0) -> Rest:
    """The IMU at rest: parked by the GNSS (for margin_s either side, the IMU's stamps
    moved by offset_s, so a clock off by less than the margin cannot put a moment of
    driving in) with the gyro quiet; failing 2 s of that, steady by the IMU alone (no turn
    above 0.3 deg/s and the specific force unchanged for a second: also a straight road
    at a steady speed); failing that, up is the drive's mean specific force and the bias 0.
    Turning steadily is not rest: the centripetal acceleration would tilt the up axis."""
    t, accel, gyro = np.asarray(t_s, float), np.asarray(accel, float), np.asarray(gyro, float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    rate = moving_average(t, gyro, 1.0)
    if motion is not None:
        parked = np.interp(t + offset_s, motion.t_s, motion.parked(margin_s).astype(float)) > 0.99
        if parked.sum() * dt >= 2.0:
            quiet = parked & (np.linalg.norm(rate - np.median(gyro[parked], axis=0), axis=1) < 0.01)
            if quiet.sum() * dt >= 2.0:
                return _rest(quiet, accel, gyro, dt, "parked")
    mean = moving_average(t, accel, 1.0)
    change = np.linalg.norm(np.column_stack([np.interp(t + 0.5, t, mean[:, k]) - np.interp(t - 0.5, t, mean[:, k])
                                             for k in range(3)]), axis=1)
    steady = (np.linalg.norm(rate, axis=1) < 0.005) & (change < 0.1)
    if steady.sum() * dt >= 2.0:
        return _rest(steady, accel, gyro, dt, "steady")
    up = accel.mean(axis=0)
    return Rest(np.zeros(len(t), bool), up / np.linalg.norm(up), np.zeros(3), 0.0, "mean of the drive")


def _rest(still: np.ndarray, accel: np.ndarray, gyro: np.ndarray, dt: float, how: str) -> Rest:
    up = accel[still].mean(axis=0)
    return Rest(still, up / np.linalg.norm(up), gyro[still].mean(axis=0), float(still.sum() * dt), how)


class ImuTrack:
    """What the IMU says happened between two moments, from its own samples: how far it
    turned about its up axis, and the specific force it felt, summed in its axes at the
    first moment, turned along about that axis only.

    A car turns about the vertical. The gyro's other axes are left out: a MEMS gyro's
    axes are misaligned by milliradians and cross-coupled by up to a few per cent, so its
    yaw rate leaks into roll and pitch, and a frame tilted by them leans gravity
    (9.8 m/s^2) into the horizontal, in step with the turns, as a turned board would.
    What the car itself pitches and rolls within a second is left to the GNSS's attitude
    at the interval's start (model/motion.py, GnssMotion.attitude).

    Each sample is the mean over the time since the previous one (an integrating IMU, and
    how the estimator uses it), so the sums are exact at the stamps and linear between."""

    def __init__(self, t_s, accel, gyro, up, gyro_bias=(0.0, 0.0, 0.0)):
        self.t_s = t = np.asarray(t_s, float)
        self.up = np.asarray(up, float) / np.linalg.norm(up)
        dt = np.diff(t, prepend=t[0] - (float(np.median(np.diff(t))) if len(t) > 1 else 0.0))
        self.dt = np.clip(dt, 0.0, None)
        rate = (np.asarray(gyro, float) - np.asarray(gyro_bias, float)) @ self.up
        self.turned = np.cumsum(rate * self.dt)                        # at each stamp
        mid = _turn_about(self.up, self.turned - rate * self.dt / 2, np.asarray(accel, float))
        self._force = np.cumsum(mid * self.dt[:, None], axis=0)

    def turn(self, t_s) -> np.ndarray:
        """The angle turned about the up axis since the first sample, at times t_s (rad)."""
        return np.interp(t_s, self.t_s, self.turned)

    def increments(self, a, b) -> np.ndarray:
        """The specific force integrated from a to b, in the IMU's axes at a (... x 3)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        df = np.stack([np.interp(b, self.t_s, self._force[:, k]) - np.interp(a, self.t_s, self._force[:, k])
                       for k in range(3)], -1)
        return _turn_about(self.up, -self.turn(a), df)

    def rate(self, t_s) -> np.ndarray:
        """The rate about the up axis at times t_s: the mean over two samples either side
        (a car's yaw rate bends sharply where the wheel starts and stops turning)."""
        half = 2.0 * float(np.median(self.dt))
        t = np.asarray(t_s, float)
        return (self.turn(t + half) - self.turn(t - half)) / (2 * half)


def _turn_about(axis: np.ndarray, angle: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v (... x 3) turned by angles (...) about one unit axis (Rodrigues)."""
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return v * c + np.cross(axis, v) * s + axis * (v @ axis)[..., None] * (1.0 - c)


def moving_average(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Mean of x over +-window_s/2 around each t (x may be n x k), by cumulative sums."""
    x = np.asarray(x, float)
    flat = x.reshape(len(t), -1)
    csum = np.vstack([np.zeros((1, flat.shape[1])), np.cumsum(flat, axis=0)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    out = (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)[:, None]
    return out.reshape(x.shape)
