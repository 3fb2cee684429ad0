"""The pilot's decisions: a plain object given events and their times; no clock, no I/O.

    pilot = Pilot(PilotSettings())
    pilot.set_route(route)                    # RouteError if it cannot be followed from here
    pilot.on_estimate(estimate)               # each estimator state, as an `Estimate`
    pilot.start(now_ns)                       # None, or why it refuses
    wheel_rad = pilot.tick(now_ns)            # the angle to send now, or None: send nothing

The service calls `tick` at the setpoint rate; None while it holds a lease means: stop
sending and disarm. Modes: idle (no route, or not started), following, finished (the
route's end reached), stopped (with the reason: a safety check, a stop, an estop, the
steering's refusal). Only `start` leaves finished or stopped for following.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from viena.common.rotation import wrap_angle
from viena.common.settings import part
from viena.services.pilot.model.estimate import Estimate
from viena.services.pilot.model.path import Path, Projection
from viena.services.pilot.model.precision import Precision, PrecisionSettings
from viena.services.pilot.model.route import Route, RouteError, distance_to_route_m
from viena.services.pilot.model.safety import SafetySettings, estimate_problem, start_problem, tracking_problem
from viena.services.pilot.model.tracking import TRACKERS, Command, TrackingSettings
from viena.services.steering.model.lateral import LateralSettings, Limits, figure, limits, scheduled

#: the share of the steering's limits the pilot plans inside: a little room for the speed it
#: sees and the steering's differing by a stamp, so that the steering never has to limit it
PLAN_SHARE = 0.9
#: the lateral offset the pure-pursuit lookahead must be able to take out inside the lateral
#: acceleration limit (ISO 11270's figure: 1 m)
CORRECTABLE_OFFSET_M = 1.0

#: the mode with no route, or a route not started (a new route leaves the pilot in it)
IDLE = "idle"


@dataclass(frozen=True)
class PilotSettings:
    """[pilot]: tracking and safety (the model's; the service adds its rates)."""
    tracking: TrackingSettings = part(TrackingSettings, "turning the route into a wheel angle")
    safety: SafetySettings = part(SafetySettings, "when to refuse or stop")
    precision: PrecisionSettings = part(PrecisionSettings, "which GNSS solution it follows with")


class Pilot:
    """See the module docstring."""

    def __init__(self, settings: PilotSettings | None = None):
        self.settings = settings or PilotSettings()
        safety = self.settings.safety
        if not 0 < safety.max_start_offset_m < safety.max_cross_track_m:
            raise ValueError(f"max_start_offset_m ({safety.max_start_offset_m:g}) must be above 0 and "
                             f"below max_cross_track_m ({safety.max_cross_track_m:g}): a start "
                             f"allowed there would stop at once")
        self.precision = Precision(self.settings.precision)     # ValueError if its settings are wrong
        self.mode = IDLE
        self.reason: str | None = None
        self.route: Route | None = None
        self.estimate: Estimate | None = None
        self.where: Projection | None = None
        self.command: Command | None = None
        self.setpoints = 0
        self._path: Path | None = None
        self._path_origin: tuple | None = None
        self._last_wheel_rad: float | None = None
        self._last_ns: int | None = None
        self.envelope: LateralSettings | None = None   # the steering's figures (its arm reply)
        self._slew_deg_s = 0.0
        self._armed_ns: int | None = None
        self.steering_speed_mps: float | None = None   # the speed the steering's envelope uses now

    # -- events -----------------------------------------------------------------------------------
    def set_route(self, route: Route) -> None:
        """Take a new route (not while following: stop first). Refused with RouteError
        when the car is known and too far from it."""
        why = self.route_problem()
        if why is not None:
            raise RouteError(why)
        est = self.estimate
        limit = self.settings.safety.max_route_distance_m
        if est is not None and est.lat_deg is not None and est.lon_deg is not None:
            far = distance_to_route_m(route, est.lat_deg, est.lon_deg)
            if far > limit:
                raise RouteError(f"the route's nearest checkpoint is {far / 1000:.1f} km from the car "
                                 f"(at most {limit:.0f} m)")
        self.route = route
        self._path, self._path_origin, self.where, self.command = None, None, None, None
        self.mode, self.reason = IDLE, None

    def route_problem(self) -> str | None:
        """Why no route is taken now, whatever it is (read before reading a route: a route
        sent while following is refused without the cost of reading it)."""
        if self.mode == "following":
            return "the pilot is following a route: send stop first"
        return None

    def on_estimate(self, est: Estimate) -> None:
        self.estimate = est

    def on_armed(self, figures: dict | None, now_ns: int, target_deg: float | None = None) -> None:
        """The steering armed for us, its target at `target_deg`: the rates start from there.
        `figures` is its arm reply's `envelope` (None from an older steering: then the pilot
        keeps only its own clamp). ValueError if malformed."""
        self._armed_ns = now_ns
        if target_deg is not None and math.isfinite(target_deg):
            self._last_wheel_rad, self._last_ns = math.radians(target_deg), now_ns
        if figures is not None:
            self.envelope = LateralSettings.from_dict(figures)
            self._slew_deg_s = figure(figures, "slew_deg_s")

    def start(self, now_ns: int) -> str | None:
        """Begin following; None, or the reason it refuses (also kept in `reason`)."""
        if self.mode == "following":
            return None
        why = self._start_problem(now_ns)
        if why is not None:
            self.reason = why
            return why
        self.mode, self.reason, self.setpoints = "following", None, 0
        return None

    def stop(self, reason: str) -> None:
        """Stop steering (a stop command, an estop, the steering's refusal). Idle stays idle."""
        if self.mode == "following":
            self.mode, self.reason = "stopped", reason
            self._last_wheel_rad = None

    def tick(self, now_ns: int) -> float | None:
        """The wheel angle to command now (rad, positive left), or None."""
        self._locate(now_ns)
        self.precision.judge(self.estimate, now_ns)
        if self.mode != "following":
            return None
        why = estimate_problem(self.estimate, now_ns, self.settings.safety)
        if why is None and self.precision.stops:
            why = self.precision.reason
        est, where, path = self.estimate, self.where, self._path
        if why is None and where is None:
            why = "lost the route"
        if why is None:
            assert where is not None and path is not None, "a place on the route is a place on its path"
            if where.s_m >= path.length_m:
                self.mode, self.reason, self._last_wheel_rad = "finished", "route end", None
                return None
            why = tracking_problem(where, self.settings.safety)
        if why is not None:
            self.stop(why)
            return None
        assert est is not None and where is not None and path is not None, "no problem: an estimate on the path"
        tracker = TRACKERS[self.settings.tracking.controller]
        speed = max(est.speed_mps, self.steering_speed_mps or 0.0)
        self.command = tracker(path, where, est.x_m, est.y_m, est.yaw_rad,
                               est.speed_mps, self.settings.tracking, self._lookahead_floor_m(speed))
        wheel = self._inside_envelope(self.command.wheel_rad, speed, now_ns)
        self._last_wheel_rad, self._last_ns = wheel, now_ns
        self.setpoints += 1
        return wheel

    def _planning_limits(self, speed_mps: float, now_ns: int) -> Limits:
        env = self.envelope
        assert env is not None, "the planning limits are the envelope's: asked only when there is one"
        engaging = self._armed_ns is not None and (now_ns - self._armed_ns) * 1e-9 < env.engage_s
        return limits(speed_mps, env.scaled(PLAN_SHARE), PLAN_SHARE * self._slew_deg_s, engaging)

    def _inside_envelope(self, wheel_rad: float, speed_mps: float, now_ns: int) -> float:
        """The tracker's angle within the steering's limits at `speed_mps` (model/lateral.py,
        the same definition the steering enforces), PLAN_SHARE of them: the widest angle,
        and the rate since the last command."""
        if self.envelope is None:
            return wheel_rad
        lim = self._planning_limits(speed_mps, now_ns)
        deg = max(-lim.max_wheel_deg, min(lim.max_wheel_deg, math.degrees(wheel_rad)))
        if self._last_wheel_rad is not None and self._last_ns is not None:
            last = math.degrees(self._last_wheel_rad)
            step = lim.rate_deg_s(max(abs(last), abs(deg))) * max(0.0, (now_ns - self._last_ns) * 1e-9)
            deg = max(last - step, min(last + step, deg))
        return math.radians(deg)

    def _lookahead_floor_m(self, speed_mps: float) -> float:
        """Pure pursuit's shortest lookahead at this speed: one that takes out
        CORRECTABLE_OFFSET_M inside the lateral acceleration limit (curvature 2 x / ld^2 at
        most a / v^2), so a small offset never asks for more than the envelope allows."""
        if self.envelope is None:
            return 0.0
        env = self.envelope
        accel = PLAN_SHARE * scheduled(speed_mps, env.lateral_speeds_mps, env.lateral_accel_mps2)
        return speed_mps * math.sqrt(2.0 * CORRECTABLE_OFFSET_M / accel) if accel > 0 else 0.0

    # -- internals --------------------------------------------------------------------------------
    def _start_problem(self, now_ns: int) -> str | None:
        if self.route is None:
            return "no route: send one on pilot/route"
        why = estimate_problem(self.estimate, now_ns, self.settings.safety)
        if why is not None:
            return why
        self.precision.judge(self.estimate, now_ns)
        if self.precision.stops:
            return self.precision.reason
        self.where = None                       # find the car afresh, from the route's start
        self._locate(now_ns)
        est, where, path = self.estimate, self.where, self._path
        assert est is not None and where is not None and path is not None, \
            "an estimate with no problem has a position: _locate put it on the route's path"
        safety, length = self.settings.safety, path.length_m
        why = start_problem(where, length, est.yaw_rad, safety)
        if where.s_m > length / 2:
            # A route that ends where it starts (a loop) has a car just behind its start
            # beside its last leg too, on a bend nearer: a drive starts at the start, where
            # the car may start.
            at_start = path.project(est.x_m, est.y_m, near_s_m=0.0)
            if (math.hypot(est.x_m - at_start.x_m, est.y_m - at_start.y_m) <= safety.max_start_offset_m
                    and start_problem(at_start, length, est.yaw_rad, safety) is None):
                self.where, why = at_start, None
        return why

    def _locate(self, now_ns: int) -> None:
        """Where the car is on the path, from the newest usable estimate (kept as it was
        when there is none)."""
        est = self.estimate
        if self.route is None or est is None or est.origin is None or not est.position_valid:
            return
        if self._path is None or est.origin != self._path_origin:
            self._path = Path.from_route(self.route, est.origin)
            self._path_origin = est.origin      # progress along the path is the same in any frame
        near = self.where.s_m if self.where is not None else None
        self.where = self._path.project(est.x_m, est.y_m, near_s_m=near)

    def snapshot(self, now_ns: int, seq: int, armed: bool) -> dict:
        """The state sample (viena.pilot.state/1)."""
        s = self.settings
        est, where, path = self.estimate, self.where, self._path
        state: dict = {
            "t": now_ns, "seq": seq, "mode": self.mode, "reason": self.reason,
            "controller": s.tracking.controller, "armed": armed,
            "route_points": 0 if self.route is None else len(self.route),
            "route_length_m": None, "checkpoint": None, "checkpoint_distance_m": None,
            "checkpoint_bearing_deg": None, "checkpoint_heading_error_deg": None,
            "progress_m": None, "progress": None, "cross_track_m": None, "heading_error_deg": None,
            "wheel_cmd_deg": None if self._last_wheel_rad is None else math.degrees(self._last_wheel_rad),
            "lookahead_m": None, "target_enu_m": None, "route_speed_mps": None,
            "estimate_age_s": None if est is None else (now_ns - est.t_ns) * 1e-9,
            "setpoints": self.setpoints,
            **self.precision.report(),
        }
        if path is None or where is None or est is None:
            return state
        state["route_length_m"] = path.length_m
        state["progress_m"] = where.s_m
        state["progress"] = min(1.0, max(0.0, where.s_m / path.length_m))
        state["cross_track_m"] = where.cross_track_m
        state["heading_error_deg"] = _turn_right_deg(where.path_yaw_rad, est.yaw_rad)
        state["route_speed_mps"] = path.speeds_mps[where.segment]
        state.update(checkpoint_guidance(path, where.s_m, est.x_m, est.y_m, est.yaw_rad))
        if self.mode == "following" and self.command is not None:
            state["lookahead_m"] = self.command.lookahead_m
            state["target_enu_m"] = [self.command.target_x_m, self.command.target_y_m]
        return state


def _turn_right_deg(way_yaw_rad: float, yaw_rad: float) -> float:
    """A way minus the heading as the Titans had it: compass degrees, > 0 turn right
    (a compass heading is clockwise, minus the ENU yaw)."""
    return math.degrees(wrap_angle(yaw_rad - way_yaw_rad))


def checkpoint_guidance(path: Path, s_m: float, x_m: float, y_m: float, yaw_rad: float) -> dict:
    """The Titans' geo values to the next checkpoint ahead of progress s: its index,
    distance, bearing (from north, clockwise) and heading error (> 0: turn right)."""
    i = path.next_checkpoint(s_m)
    if i is None:
        return {"checkpoint": None}
    dx, dy = float(path.points[i, 0]) - x_m, float(path.points[i, 1]) - y_m
    bearing_yaw = math.atan2(-dx, dy)                        # the bearing as a yaw (CCW)
    return {"checkpoint": i, "checkpoint_distance_m": math.hypot(dx, dy),
            "checkpoint_bearing_deg": math.degrees(wrap_angle(-bearing_yaw)),
            "checkpoint_heading_error_deg": _turn_right_deg(bearing_yaw, yaw_rad)}
