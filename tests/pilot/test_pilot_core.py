"""The pilot's decisions on a simulated clock: starting, following, and every reason to
refuse or stop (stale, invalid or uncertain estimate, off the route, cross-track, the
route's end, stop, estop), each visible in the state."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from viena.common.geodesy import LocalFrame
from viena.common.samples.pilot import STATE
from viena.services.pilot.model.estimate import Estimate, estimate_of
from viena.services.pilot.model.pilot import Pilot, PilotSettings
from viena.services.pilot.model.route import RouteError, checked
from viena.services.sim.model.truth import IST_ORIGIN

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
FRAME = LocalFrame(*IST_ORIGIN)


def straight_north(length_m: float = 100.0, every_m: float = 10.0):
    """Checkpoints every 10 m due north from the ENU origin."""
    n = int(length_m / every_m) + 1
    pts = [FRAME.geodetic_of_enu_exact(0.0, i * every_m, IST_ORIGIN[2])[:2] for i in range(n)]
    return checked(pts, [None] * n, "points")


def est(t_ns: int = T0, x: float = 0.0, y: float = 0.0, yaw_deg: float = 0.0, **kw) -> Estimate:
    lat, lon, _ = FRAME.geodetic_of_enu_exact(x, y, IST_ORIGIN[2])
    fields = dict(t_ns=t_ns, mode="navigating", position_valid=True, heading_valid=True,
                  origin=IST_ORIGIN, x_m=x, y_m=y, yaw_rad=math.radians(yaw_deg), speed_mps=4.0,
                  sigma_h_m=0.05, lat_deg=lat, lon_deg=lon)
    fields.update(kw)
    return Estimate(**fields)


def following(**est_kw) -> Pilot:
    pilot = Pilot()
    pilot.on_estimate(est(**est_kw))
    pilot.set_route(straight_north())
    assert pilot.start(T0) is None
    assert pilot.mode == "following"
    return pilot


def state_of(pilot: Pilot, now_ns: int = T0) -> dict:
    return STATE.decode(STATE.encode(pilot.snapshot(now_ns, 0, False)))


def test_follows_and_reports_where_it_is():
    pilot = following(x=0.5, y=12.0)
    angle = pilot.tick(T0 + 10 * MS)
    assert angle is not None and angle > 0                  # half a metre east, right of it: turn left
    s = state_of(pilot, T0 + 10 * MS)
    assert s["mode"] == "following" and s["reason"] is None
    assert s["cross_track_m"] == pytest.approx(-0.5, abs=1e-3)
    assert s["progress_m"] == pytest.approx(12.0, abs=1e-3) and s["progress"] == pytest.approx(0.12, abs=1e-3)
    assert s["checkpoint"] == 2 and s["checkpoint_distance_m"] == pytest.approx(math.hypot(0.5, 8.0), abs=1e-3)
    assert s["checkpoint_heading_error_deg"] < 0            # the checkpoint is a bit to the left
    assert s["wheel_cmd_deg"] == pytest.approx(math.degrees(angle))
    assert s["lookahead_m"] == pytest.approx(3.0 + 0.6 * 4.0) and s["setpoints"] == 1
    assert s["estimate_age_s"] == pytest.approx(0.01)


def test_no_route_or_no_estimate_refuses_to_start():
    pilot = Pilot()
    assert pilot.start(T0) == "no route: send one on pilot/route"
    pilot.set_route(straight_north())
    assert pilot.start(T0) == "no estimate from the estimator"
    assert pilot.mode == "idle" and pilot.tick(T0) is None
    assert state_of(pilot)["reason"] == "no estimate from the estimator"


@pytest.mark.parametrize("change, reason", [
    (dict(t_ns=T0 - 250 * MS), "estimate stale: 250 ms old (at most 200 ms)"),
    (dict(mode="aligning"), "estimate not valid: estimator aligning"),
    (dict(mode="waiting", position_valid=False, origin=None), "estimate not valid: estimator waiting"),
    (dict(position_valid=False), "estimate not valid: no position"),
    (dict(heading_valid=False), "estimate not valid: no heading"),
    (dict(sigma_h_m=2.8), "estimate too uncertain: sigma 2.80 m (at most 2.50 m)"),
    (dict(x=5.0, y=10.0), "too far from the route: 5.0 m (at most 1.5 m)"),
    (dict(x=-1.6, y=10.0), "too far from the route: 1.6 m (at most 1.5 m)"),
    (dict(y=-6.0), "too far from the route: 6.0 m (at most 1.5 m)"),
    (dict(yaw_deg=170.0), "facing 170 deg away from the route's way (at most 60 deg)"),
    (dict(y=101.0), "at the end of the route already"),
])
def test_refuses_to_start_with_the_reason(change, reason):
    pilot = Pilot()
    pilot.set_route(straight_north())
    pilot.on_estimate(est(**change))
    assert pilot.start(T0) == reason
    assert pilot.mode == "idle" and pilot.tick(T0) is None
    assert state_of(pilot)["reason"] == reason


@pytest.mark.parametrize("change, reason", [
    (dict(mode="attitude"), "estimate not valid: estimator attitude"),
    (dict(heading_valid=False), "estimate not valid: no heading"),
    (dict(sigma_h_m=2.51), "estimate too uncertain: sigma 2.51 m (at most 2.50 m)"),
    (dict(sigma_h_m=math.inf), "estimate too uncertain: sigma inf m (at most 2.50 m)"),
    (dict(x=2.5), "cross-track error 2.50 m (at most 2.00 m)"),
])
def test_stops_while_following_with_the_reason(change, reason):
    pilot = following()
    assert pilot.tick(T0 + 20 * MS) is not None
    pilot.on_estimate(est(t_ns=T0 + 40 * MS, y=2.0, **change))
    assert pilot.tick(T0 + 40 * MS) is None
    assert (pilot.mode, pilot.reason) == ("stopped", reason)
    pilot.on_estimate(est(t_ns=T0 + 60 * MS, y=2.0))         # all well again: still stopped
    assert pilot.tick(T0 + 60 * MS) is None and pilot.mode == "stopped"
    assert pilot.start(T0 + 60 * MS) is None and pilot.tick(T0 + 60 * MS) is not None


def test_a_silent_estimator_stops_steering_by_200_ms():
    pilot = following()
    for k in range(1, 12):                                    # setpoints every 20 ms, no new estimate
        angle = pilot.tick(T0 + k * 20 * MS)
        assert (angle is not None) == (k * 20 <= 200)
    assert pilot.mode == "stopped" and pilot.reason.startswith("estimate stale: 220 ms old")


def test_coasting_on_dead_reckoning_is_followed_while_sigma_allows():
    pilot = following()
    pilot.on_estimate(est(t_ns=T0 + 20 * MS, y=1.0, mode="coasting", sigma_h_m=0.3))
    assert pilot.tick(T0 + 20 * MS) is not None


def test_route_end_finishes_and_a_new_start_begins_again():
    pilot = following(y=95.0)
    pilot.on_estimate(est(t_ns=T0 + 20 * MS, y=99.5))
    assert pilot.tick(T0 + 20 * MS) is not None
    pilot.on_estimate(est(t_ns=T0 + 40 * MS, y=100.2))
    assert pilot.tick(T0 + 40 * MS) is None
    assert (pilot.mode, pilot.reason) == ("finished", "route end")
    assert state_of(pilot, T0 + 40 * MS)["checkpoint"] is None
    assert pilot.start(T0 + 40 * MS) == "at the end of the route already"


def test_stop_and_estop_need_a_new_start():
    pilot = following()
    pilot.stop("estop")
    assert pilot.tick(T0 + 20 * MS) is None and (pilot.mode, pilot.reason) == ("stopped", "estop")
    pilot.on_estimate(est(t_ns=T0 + 40 * MS, y=0.5))
    assert pilot.tick(T0 + 40 * MS) is None
    assert pilot.start(T0 + 40 * MS) is None and pilot.tick(T0 + 40 * MS) is not None
    idle = Pilot()
    idle.stop("stop command")                                 # nothing to stop: stays idle
    assert idle.mode == "idle" and idle.reason is None


def test_routes_too_far_or_while_following_are_refused():
    pilot = Pilot()
    pilot.on_estimate(est(x=0.0, y=-10_000.0))               # 10 km south of the route
    with pytest.raises(RouteError, match="10.0 km from the car"):
        pilot.set_route(straight_north())
    assert pilot.route is None
    pilot = following()
    with pytest.raises(RouteError, match="send stop first"):
        pilot.set_route(straight_north(50.0))
    assert pilot.mode == "following" and len(pilot.route) == 11


def test_a_new_origin_keeps_the_progress():
    """The estimator may re-anchor its ENU frame: the path is rebuilt there, and the car is
    where it was along it."""
    pilot = following(y=20.0)
    pilot.tick(T0 + 20 * MS)
    origin = FRAME.geodetic_of_enu_exact(0.0, 20.0, IST_ORIGIN[2])
    pilot.on_estimate(est(t_ns=T0 + 40 * MS, origin=tuple(origin), x=0.0, y=0.5))
    assert pilot.tick(T0 + 40 * MS) is not None
    assert pilot.where.s_m == pytest.approx(20.5, abs=0.01)


def test_a_start_allowed_where_it_would_stop_at_once_is_refused_as_a_setting():
    settings = PilotSettings()
    with pytest.raises(ValueError, match="must be above 0 and below max_cross_track_m"):
        Pilot(replace(settings, safety=replace(settings.safety, max_start_offset_m=2.5)))


def test_stanley_is_a_setting():
    settings = PilotSettings()
    pilot = Pilot(replace(settings, tracking=replace(settings.tracking, controller="stanley")))
    pilot.on_estimate(est(x=-0.5, y=10.0))
    pilot.set_route(straight_north())
    pilot.start(T0)
    assert pilot.tick(T0) < 0
    assert state_of(pilot)["controller"] == "stanley"


def test_estimate_read_from_an_estimator_state():
    state = {"t": T0, "mode": "navigating", "position_valid": True, "heading_valid": True,
             "origin": list(IST_ORIGIN), "enu_m": [1.0, 2.0, 0.0], "yaw_rad": 0.1, "speed_mps": 3.0,
             "sigma_h_m": 0.2, "lat_deg": 38.7, "lon_deg": -9.1}
    e = estimate_of(state)
    assert (e.x_m, e.y_m, e.yaw_rad, e.origin, e.sigma_h_m) == (1.0, 2.0, 0.1, IST_ORIGIN, 0.2)
    from viena.common.errors import SampleError
    with pytest.raises(SampleError, match="enu_m"):
        estimate_of({**state, "enu_m": [float("nan"), 0.0, 0.0]})


def test_the_pilot_plans_inside_the_envelope_the_steering_gave():
    """Issue 26: 1.4 m off the route at 14 m/s a tracker asks for several degrees; the pilot
    sends no more than 90 % of what the steering's envelope allows at the speed (the higher
    of its estimate's and the steering's), and turns toward it no faster than its rate."""
    from viena.services.steering.model.lateral import LateralSettings, lateral_accel_mps2, limits

    envelope = LateralSettings()
    pilot = following(x=1.4, y=12.0, speed_mps=14.0)
    pilot.on_armed({**envelope.as_dict(), "slew_deg_s": 30.0}, T0, 0.0)
    pilot.steering_speed_mps = 14.3
    angles = []
    for k in range(1, 200):                      # the car held where it is: the command's limits alone
        pilot.on_estimate(est(T0 + k * 20 * MS, x=1.4, y=12.0, speed_mps=14.0))
        angles.append(math.degrees(pilot.tick(T0 + k * 20 * MS)))
    allowed = limits(14.3, envelope, 30.0)
    assert max(abs(a) for a in angles) <= 0.9 * allowed.max_wheel_deg + 1e-9
    assert max(lateral_accel_mps2(14.3, a, envelope.wheelbase_m) for a in angles) < 3.0
    steps = [abs(b - a) / 0.02 for a, b in zip([0.0, *angles], angles)]
    assert max(steps) <= allowed.rate_deg_s(max(abs(a) for a in angles)) + 1e-9
    assert angles[-1] > 0.9 * 0.9 * allowed.max_wheel_deg         # it does turn, as far as it may


def test_an_unreadable_envelope_is_refused():
    pilot = following()
    with pytest.raises(ValueError):
        pilot.on_armed({"lateral_accel_mps2": [float("nan")], "slew_deg_s": 30.0}, T0, 0.0)
    with pytest.raises(ValueError):
        pilot.on_armed({"lateral_speeds_mps": [8.0], "lateral_accel_mps2": [7.0, 3.0], "slew_deg_s": 30.0}, T0)


def test_a_loop_starts_at_its_start_for_a_car_just_behind_it_on_a_bend():
    """A route that ends where it starts: a car just behind the start is beside the last
    leg too, and nearer it here; the drive starts at the start, not at the end (which
    finished it at once)."""
    # north from the origin, round, and back into it from the south-south-west
    corners = [(0.0, 0.0), (0.0, 20.0), (20.0, 20.0), (20.0, -10.0), (-5.0, -10.0), (0.0, 0.0)]
    pts = [FRAME.geodetic_of_enu_exact(x, y, IST_ORIGIN[2])[:2] for x, y in corners]
    pilot = Pilot()
    pilot.on_estimate(est(x=-0.9, y=-1.2, yaw_deg=0.0))     # 0.9 m off the first leg, 0.27 m off the last
    pilot.set_route(checked(pts, [None] * len(pts), "points"))
    assert pilot.start(T0) is None
    s = state_of(pilot)
    assert s["mode"] == "following" and s["progress_m"] == pytest.approx(-1.2, abs=1e-2)
    pilot.tick(T0 + 10 * MS)
    assert pilot.mode == "following"
