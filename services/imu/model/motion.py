"""The car's motion as a GNSS receiver sees it: what an IMU's mount and clock are checked
against (`viena calibrate imu mount|time`).

From the fixes' velocities only (Doppler velocity is smooth where positions are not):
speed, the yaw the course implies, the yaw rate and the forward acceleration, each on the
receiver's own clock corrected by the velocity's reported latency. Body frame x right,
y forward, z up; yaw 0 points north and grows counter-clockwise (docs/frames.md).

The car points where it goes only at the point that does not slip sideways, the rear
axle, which is the body origin. An antenna a metre ahead of it moves sideways in a turn
(velocity = v_origin + omega x lever arm), so its course leads the heading by
atan(lever_y omega / v): at 4 m/s that looks like a quarter of a second. The antenna's
lever arm takes this out, so the motion is the body origin's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.common.errors import SampleError
from viena.common.geodesy import LocalFrame
from viena.services.gnss.model.fix import read_fix

#: below this speed the course says nothing about where the car points
MOVING_MPS = 2.0
#: a receiver's Doppler speed stays below this when the car stands still (noise ~0.03 m/s)
PARKED_MPS = 0.1
#: below this speed a Doppler course is mostly noise: the heading is held
SLOW_MPS = 0.5


@dataclass(frozen=True)
class GnssMotion:
    """Arrays on one time axis, t_s (seconds on the UTC clock of the fixes)."""

    t_s: np.ndarray
    speed_mps: np.ndarray
    yaw_rad: np.ndarray            # unwrapped, from the course; meaningless when slow
    yaw_rate_radps: np.ndarray
    forward_accel_mps2: np.ndarray

    @property
    def moving(self) -> np.ndarray:
        return self.speed_mps > MOVING_MPS

    def parked(self, margin_s: float) -> np.ndarray:
        """Standing still, and for margin_s before and after."""
        slow = self.speed_mps < PARKED_MPS
        start = np.searchsorted(self.t_s, self.t_s - margin_s, side="left")
        end = np.searchsorted(self.t_s, self.t_s + margin_s, side="right")
        fast_before = np.concatenate([[0], np.cumsum(~slow)])
        return (fast_before[end] - fast_before[start]) == 0

    def lateral_accel_mps2(self) -> np.ndarray:
        """What the accelerometer's x axis (right) feels in a turn: the centripetal
        acceleration points left (-x) in a left turn (positive yaw rate)."""
        return -self.speed_mps * self.yaw_rate_radps


def gnss_motion(fixes: list[dict], lever_arm_m=(0.0, 0.0, 0.0), smooth_s: float = 0.3) -> GnssMotion:
    """Motion of the body origin from valid fixes with a velocity (viena.gnss.fix/1 dicts)
    of an antenna at `lever_arm_m` (body frame, from the origin).

    Derivatives are central differences over `smooth_s`, so they are as smooth as the
    IMU signals they are compared with (which get the same window)."""
    rows = []
    for sample in fixes:
        try:
            fix = read_fix(sample)
        except SampleError:
            continue
        if fix.usable and fix.has_velocity:
            rows.append(fix)
    if len(rows) < 10:
        raise ValueError(f"{len(rows)} fixes with a velocity: need a drive of at least a few seconds")
    frame = LocalFrame.at_ecef(rows[0].ecef_m)
    t = np.array([f.t * 1e-9 - f.vel_latency_s for f in rows])
    vel = np.array([f.vel_ecef_mps for f in rows], float) @ frame.rot_ecef_to_enu.T
    order = np.argsort(t)
    t, vel = t[order], vel[order]
    ant_speed = np.hypot(vel[:, 0], vel[:, 1])
    course = np.unwrap(np.arctan2(-vel[:, 0], vel[:, 1]))
    arm_x, arm_y = float(lever_arm_m[0]), float(lever_arm_m[1])
    yaw = _yaw_of_course(t, course, ant_speed, arm_x, arm_y)
    rate = np.where(ant_speed < SLOW_MPS, 0.0, _derivative(t, yaw, smooth_s))
    speed = np.maximum(ant_speed ** 2 - (rate * arm_y) ** 2, 0.0) ** 0.5 - rate * arm_x
    return GnssMotion(t, speed, yaw, rate, _derivative(t, speed, smooth_s))


def _yaw_of_course(t: np.ndarray, course: np.ndarray, ant_speed: np.ndarray,
                   arm_x: float, arm_y: float) -> np.ndarray:
    """The heading whose turn makes the antenna's course: course = yaw + slip, with
    slip = atan2(rate arm_y, v + rate arm_x) and rate = d yaw / dt. Solved step by step
    (implicitly, by Newton's method), so no derivative of a derivative amplifies noise."""
    slow = ant_speed < SLOW_MPS
    yaw = course.copy()
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        if slow[k] or slow[k - 1] or dt <= 0 or arm_y == 0.0:
            continue                 # standing, or starting again: the course as it is
        y = yaw[k - 1] + (course[k] - course[k - 1])
        for _ in range(4):
            rate = (y - yaw[k - 1]) / dt
            forward = ant_speed[k] + rate * arm_x
            slip = math.atan2(rate * arm_y, forward)
            d_slip = (arm_y * forward - rate * arm_y * arm_x) / (forward ** 2 + (rate * arm_y) ** 2) / dt
            y -= (y + slip - course[k]) / (1.0 + d_slip)
        yaw[k] = y
    # standing still the car does not turn: hold the heading it had (or will have) moving
    moving = np.flatnonzero(~slow)
    if len(moving):
        nearest = moving[np.clip(np.searchsorted(moving, np.arange(len(t)), side="right") - 1, 0, None)]
        nearest = np.where(np.arange(len(t)) < moving[0], moving[0], nearest)
        yaw[slow] = yaw[nearest[slow]]
    return yaw


def _derivative(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """d x / d t by central differences half a window either side (edges: one-sided)."""
    before = np.searchsorted(t, t - window_s / 2, side="left")
    after = np.clip(np.searchsorted(t, t + window_s / 2, side="right") - 1, 0, len(t) - 1)
    dt = t[after] - t[before]
    out = np.zeros_like(x)
    ok = dt > 0
    out[ok] = (x[after] - x[before])[ok] / dt[ok]
    return out


def moving_average(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Mean of x over +-window_s/2 around each t (x may be n x k), by cumulative sums."""
    x = np.asarray(x, float)
    flat = x.reshape(len(t), -1)
    csum = np.vstack([np.zeros((1, flat.shape[1])), np.cumsum(flat, axis=0)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    out = (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)[:, None]
    return out.reshape(x.shape)
