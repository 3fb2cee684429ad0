"""The wheel angle that follows the path: pure pursuit, or Stanley (a setting).

Both take the car's pose at the centre of the rear axle (the body origin, docs/frames.md),
its yaw and its speed, and return the bicycle model's front-wheel angle in rad, positive
left (docs/steering.md#the-bicycle-model), within the wheel's lock.

Pure pursuit (Coulter, CMU-RI-TR-92-01; as Autoware's pure_pursuit writes it): aim at the
path's point one lookahead distance ahead of the car's projection, and steer onto the arc
through the rear axle that reaches it, curvature k = 2 x_left / d^2 (x_left: the target's
sideways offset in the car's frame, d: its distance), wheel = atan(L k). The lookahead
grows with speed, ld = clamp(ld_min + gain * v, ld_min, ld_max): short in slow tight
turns, long (smooth, stable) when fast. On a circle the arc is exact in steady state.

Stanley (Thrun et al. 2006, the DARPA Grand Challenge's Stanley): at the front axle,
wheel = heading error + atan(k e / (v_soft + v)), e the front axle's cross-track error
toward the path. Reacts to the error directly: tighter on straights, needs a smooth path.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from viena.common.rotation import wrap_angle
from viena.common.settings import setting
from viena.services.pilot.model.path import Path, Projection

CONTROLLERS = ("pure_pursuit", "stanley")


@dataclass(frozen=True)
class TrackingSettings:
    """How the pilot turns the path into a wheel angle."""
    controller: str = setting("pure_pursuit", "the path tracker", choices=CONTROLLERS)
    wheelbase_m: float = setting(2.2, "distance between the axles (the bicycle model's L)")
    max_wheel_angle_deg: float = setting(27.0, "largest wheel angle commanded, inside the steering's range")
    lookahead_min_m: float = setting(3.0, "pure pursuit's lookahead when standing")
    lookahead_gain_s: float = setting(0.6, "... plus this many seconds of travel at the car's speed")
    lookahead_max_m: float = setting(12.0, "... up to this far")
    stanley_gain: float = setting(1.5, "Stanley's cross-track gain k (1/s: per m/s of speed)")
    stanley_soft_mps: float = setting(1.0, "Stanley's softening speed, so a slow car is not jerked")


@dataclass(frozen=True)
class Command:
    """A tracker's answer: the wheel angle and what it aimed at (for the state and plots)."""
    wheel_rad: float
    target_x_m: float
    target_y_m: float
    lookahead_m: float


def lookahead_m(speed_mps: float, s: TrackingSettings, floor_m: float = 0.0) -> float:
    """The settings' lookahead at this speed, at least `floor_m` (the steering envelope's:
    services/pilot/model/pilot.py), which may pass lookahead_max_m."""
    ld = s.lookahead_min_m + s.lookahead_gain_s * max(0.0, speed_mps)
    return max(min(max(ld, s.lookahead_min_m), s.lookahead_max_m), floor_m)


def _clamp_wheel(angle_rad: float, s: TrackingSettings) -> float:
    lim = math.radians(s.max_wheel_angle_deg)
    return max(-lim, min(lim, angle_rad))


def pure_pursuit(path: Path, where: Projection, x_m: float, y_m: float, yaw_rad: float,
                 speed_mps: float, s: TrackingSettings, lookahead_floor_m: float = 0.0) -> Command:
    ld = lookahead_m(speed_mps, s, lookahead_floor_m)
    gx, gy = path.point_at(where.s_m + ld)
    dx, dy = gx - x_m, gy - y_m
    c, sn = math.cos(yaw_rad), math.sin(yaw_rad)
    right, forward = c * dx + sn * dy, -sn * dx + c * dy      # the target in body axes
    d2 = right * right + forward * forward
    if d2 < 1e-6:
        return Command(0.0, gx, gy, ld)
    curvature = -2.0 * right / d2                              # target on the left: turn left
    return Command(_clamp_wheel(math.atan(s.wheelbase_m * curvature), s), gx, gy, ld)


def stanley(path: Path, where: Projection, x_m: float, y_m: float, yaw_rad: float,
            speed_mps: float, s: TrackingSettings, lookahead_floor_m: float = 0.0) -> Command:
    """(`lookahead_floor_m` is pure pursuit's; Stanley looks at the front axle.)"""
    fx, fy = x_m - s.wheelbase_m * math.sin(yaw_rad), y_m + s.wheelbase_m * math.cos(yaw_rad)
    front = path.project(fx, fy, near_s_m=where.s_m + s.wheelbase_m)
    heading_error = wrap_angle(front.path_yaw_rad - yaw_rad)
    correction = math.atan2(s.stanley_gain * front.cross_track_m, s.stanley_soft_mps + max(0.0, speed_mps))
    return Command(_clamp_wheel(heading_error - correction, s), front.x_m, front.y_m, s.wheelbase_m)


TRACKERS = {"pure_pursuit": pure_pursuit, "stanley": stanley}
