"""The simulated car: a kinematic bicycle model (docs/steering.md#the-bicycle-model) that drives a default route.

The car is the hardware of the simulation: every device twin reads its truth. The wheel
angle comes from the built-in route follower (pure pursuit around a loop at the campus),
or, once the steering drive's twin is attached, from the drive itself.
"""
from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

from viena.common import clock
from viena.common.geodesy import normal_gravity
from viena.common.rotation import quat_floats_from_euler
from viena.common.settings import setting
from viena.services.sim.model.route import Route, default_route
from viena.services.sim.model.truth import IST_ORIGIN, Truth


@dataclass(frozen=True)
class CarParams:
    """The simulated car and how it drives its route (settings of `viena-sim`)."""
    wheelbase_m: float = setting(2.2, "distance between the axles")
    max_wheel_angle_rad: float = setting(math.radians(29.0), "the front wheel's lock (29 deg)")
    max_wheel_rate_radps: float = setting(math.radians(30.0),
                                          "how fast the route follower turns the wheel (30 deg/s)")
    lookahead_m: float = setting(6.0, "pure pursuit's look-ahead along the route")
    parked_s: float = setting(10.0, "standing still first, as a car does while its IMU aligns")
    speed_min_mps: float = setting(3.0, "slowest speed round the loop")
    speed_max_mps: float = setting(5.0, "fastest speed round the loop")
    speed_period_s: float = setting(40.0, "period of the speed's sine between the two")
    max_accel_mps2: float = setting(1.0, "largest acceleration or braking")


class SimCar:
    """Bicycle model state, stepped at a fixed rate; thread-safe `truth()`.

    Integration is exact for constant speed and wheel angle over one step (arc motion),
    so accelerations and rates in the truth are consistent with the positions.
    """

    def __init__(self, params: CarParams | None = None, route: Route | None = None,
                 origin=IST_ORIGIN, start_time_ns: int | None = None):
        self.params = params or CarParams()
        self.route = route or default_route()
        self.origin = tuple(origin)
        self.gravity = normal_gravity(origin[0], origin[2])
        self._t0_ns = clock.time_ns() if start_time_ns is None else int(start_time_ns)
        x, y, yaw = self.route.start_pose()
        self._x, self._y, self._yaw = x, y, yaw
        self._v = 0.0
        self._delta = 0.0
        self._t = 0.0
        self._seq = 0
        self._wheel_source: Callable[[], float] | None = None
        self._lock = threading.Lock()
        self._truth = self._make_truth(0.0, 0.0, 0.0)

    # -- inputs -------------------------------------------------------------------------
    def set_wheel_source(self, fn: Callable[[], float] | None) -> None:
        """Let a steering twin drive the wheel angle (rad, positive left)."""
        self._wheel_source = fn

    def start_clock(self, now_ns: int | None = None) -> None:
        """Tie simulation time zero to `now_ns` (UTC): call when stepping really begins,
        so truth times agree with the wall clock the devices' clocks follow."""
        self._t0_ns = (clock.time_ns() if now_ns is None else int(now_ns)) - int(round(self._t * 1e9))

    def driver_wheel_angle(self) -> float:
        """The wheel angle a person following the route would steer to now (rad): what
        the steering twin's hands do while the drive does not hold the wheel."""
        return self._pursuit_angle()

    # -- stepping -----------------------------------------------------------------------
    def step(self, dt: float) -> Truth:
        p = self.params
        v_cmd = self._speed_command(self._t)
        dv = max(-p.max_accel_mps2 * dt, min(p.max_accel_mps2 * dt, v_cmd - self._v))
        v_new = self._v + dv
        if self._wheel_source is not None:
            delta_new = float(self._wheel_source())
        else:
            target = self._pursuit_angle()
            step = p.max_wheel_rate_radps * dt
            delta_new = self._delta + max(-step, min(step, target - self._delta))
        delta_new = max(-p.max_wheel_angle_rad, min(p.max_wheel_angle_rad, delta_new))

        v_mid = 0.5 * (self._v + v_new)
        yaw_rate = v_mid * math.tan(0.5 * (self._delta + delta_new)) / p.wheelbase_m
        yaw_new = self._yaw + yaw_rate * dt
        # forward = Rz(yaw) [0, 1, 0] = [-sin yaw, cos yaw]: arc integration
        if abs(yaw_rate) > 1e-9:
            r = v_mid / yaw_rate
            self._x += r * (math.cos(yaw_new) - math.cos(self._yaw))
            self._y += r * (math.sin(yaw_new) - math.sin(self._yaw))
        else:
            self._x += -v_mid * dt * math.sin(self._yaw)
            self._y += v_mid * dt * math.cos(self._yaw)
        self._yaw = yaw_new
        self._v, self._delta = v_new, delta_new
        self._t += dt
        along = dv / dt if dt > 0 else 0.0
        truth = self._make_truth(along, yaw_rate, v_new * yaw_rate)
        with self._lock:
            self._truth = truth
        return truth

    def truth(self) -> Truth:
        with self._lock:
            return self._truth

    # -- internals ----------------------------------------------------------------------
    def _speed_command(self, t: float) -> float:
        p = self.params
        if t < p.parked_s:
            return 0.0
        mid = 0.5 * (p.speed_min_mps + p.speed_max_mps)
        amp = 0.5 * (p.speed_max_mps - p.speed_min_mps)
        return mid + amp * math.sin(2 * math.pi * (t - p.parked_s) / p.speed_period_s)

    def _pursuit_angle(self) -> float:
        """Pure pursuit: aim at the route point one look-ahead distance ahead."""
        p = self.params
        gx, gy = self.route.lookahead(self._x, self._y, p.lookahead_m)
        dx, dy = gx - self._x, gy - self._y
        # target in body axes: x right, y forward
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        bx, by = c * dx + s * dy, -s * dx + c * dy
        ld2 = bx * bx + by * by
        if ld2 < 1e-6:
            return 0.0
        curvature = -2.0 * bx / ld2          # target to the left (bx < 0) -> turn left
        return math.atan(curvature * p.wheelbase_m)

    def _make_truth(self, along_mps2: float, yaw_rate: float, lateral_mps2: float) -> Truth:
        # v fwd and a_along fwd + a_lat left, fwd = (-s, c, 0), left = (-c, -s, 0), written
        # out in floats: the same products and sums numpy would do, without its overhead
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        v = self._v
        vel = (v * -s, v * c, v * 0.0)
        accel = (along_mps2 * -s + lateral_mps2 * -c, along_mps2 * c + lateral_mps2 * -s,
                 along_mps2 * 0.0 + lateral_mps2 * 0.0)
        self._seq += 1
        return Truth.of_floats(
            t_ns=self._t0_ns + int(round(self._t * 1e9)),
            t_s=self._t,
            origin=self.origin,
            enu_m=(self._x, self._y, 0.0),
            vel_enu_mps=vel,
            accel_enu_mps2=accel,
            quat=quat_floats_from_euler(self._yaw, 0.0, 0.0),
            gyro_body_radps=(0.0, 0.0, yaw_rate),
            speed_mps=self._v,
            wheel_angle_rad=self._delta,
            gravity_mps2=self.gravity,
            seq=self._seq,
        )
