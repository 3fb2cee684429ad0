"""The tracking maths on their own: the path's geometry, the two trackers' signs, and a
whole loop of the sim's kinematic bicycle steered by the pilot's model, against the truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.pilot import drive_loop
from viena.services.pilot.model.path import Path
from viena.services.pilot.model.pilot import checkpoint_guidance
from viena.services.pilot.model.tracking import TrackingSettings, lookahead_m, pure_pursuit, stanley

NORTH = Path([(0.0, 0.0), (0.0, 10.0), (0.0, 20.0)])       # a straight road northwards
SETTINGS = TrackingSettings()


def test_projection_progress_sign_and_ends():
    where = NORTH.project(-1.0, 4.0)                          # a metre west: left of a northbound road
    assert where.s_m == pytest.approx(4.0) and where.cross_track_m == pytest.approx(1.0)
    assert where.path_yaw_rad == pytest.approx(0.0)
    assert NORTH.project(2.0, 15.0).cross_track_m == pytest.approx(-2.0)
    assert NORTH.project(0.0, 23.0).s_m == pytest.approx(23.0)    # beyond the end: along the last leg
    assert NORTH.project(0.0, -2.0).s_m == pytest.approx(-2.0)
    assert NORTH.point_at(25.0) == pytest.approx((0.0, 25.0))
    far_beyond = NORTH.project(0.0, 60.0, near_s_m=50.0)           # the window past the end
    assert far_beyond.s_m == pytest.approx(60.0) and far_beyond.segment == 1
    assert NORTH.project(0.5, -30.0, near_s_m=-30.0).s_m == pytest.approx(-30.0)
    east = Path([(0.0, 0.0), (10.0, 0.0)])
    assert east.project(3.0, 0.5).path_yaw_rad == pytest.approx(-math.pi / 2)   # yaw CCW from north


def test_a_position_that_is_not_finite_is_refused_not_projected():
    for near in (None, 4.0):
        with pytest.raises(ValueError, match="finite"):
            NORTH.project(math.nan, 4.0, near_s_m=near)
        with pytest.raises(ValueError, match="finite"):
            NORTH.project(0.0, math.inf, near_s_m=near)


def test_closed_loop_start_is_found_at_its_start_then_followed_to_its_end():
    square = Path([(0, 0), (0, 10), (-10, 10), (-10, 0), (0, 0)])
    assert square.project(0.2, 0.1).s_m == pytest.approx(0.1)      # not 40: the earliest wins
    near = 0.1
    for y in np.arange(1.0, 10.0):
        near = square.project(0.0, y, near_s_m=near).s_m
    for s in np.arange(11.0, 40.5, 1.0):                           # all the way round
        x, y = square.point_at(s)
        near = square.project(x, y, near_s_m=near).s_m
    assert near == pytest.approx(40.0)


@pytest.mark.parametrize("tracker", [pure_pursuit, stanley])
def test_trackers_steer_back_towards_the_road(tracker):
    left = NORTH.project(-1.0, 5.0)
    assert tracker(NORTH, left, -1.0, 5.0, 0.0, 4.0, SETTINGS).wheel_rad < 0     # left of it: turn right
    right = NORTH.project(1.0, 5.0)
    assert tracker(NORTH, right, 1.0, 5.0, 0.0, 4.0, SETTINGS).wheel_rad > 0
    on = NORTH.project(0.0, 5.0)
    assert tracker(NORTH, on, 0.0, 5.0, 0.0, 4.0, SETTINGS).wheel_rad == pytest.approx(0.0, abs=1e-9)
    skew = tracker(NORTH, on, 0.0, 5.0, math.radians(20), 4.0, SETTINGS)           # facing NW
    assert skew.wheel_rad < 0


def test_pure_pursuit_holds_a_circle_and_its_lookahead_grows_with_speed():
    r = 12.0
    a = np.linspace(0, math.pi, 200)
    arc = Path(np.column_stack([r * np.cos(a), r * np.sin(a)]))      # CCW from (12, 0), heading north
    where = arc.project(r, 0.0)
    cmd = pure_pursuit(arc, where, r, 0.0, 0.0, 4.0, SETTINGS)
    assert cmd.wheel_rad == pytest.approx(math.atan(SETTINGS.wheelbase_m / r), rel=0.01)
    assert lookahead_m(0.0, SETTINGS) == SETTINGS.lookahead_min_m
    assert lookahead_m(3.0, SETTINGS) < lookahead_m(8.0, SETTINGS) <= SETTINGS.lookahead_max_m
    assert lookahead_m(100.0, SETTINGS) == SETTINGS.lookahead_max_m


def test_wheel_angle_stays_within_its_lock():
    where = NORTH.project(-3.0, 1.0)
    limit = math.radians(SETTINGS.max_wheel_angle_deg)
    for tracker in (pure_pursuit, stanley):
        assert abs(tracker(NORTH, where, -3.0, 1.0, math.radians(150), 1.0, SETTINGS).wheel_rad) <= limit


def test_checkpoint_guidance_is_the_titans_geo_values():
    # standing at the start, facing north; the next checkpoint is 10 m north
    g = checkpoint_guidance(NORTH, 0.0, 0.0, 0.0, 0.0)
    assert g["checkpoint"] == 1 and g["checkpoint_distance_m"] == pytest.approx(10.0)
    assert g["checkpoint_bearing_deg"] == pytest.approx(0.0)
    assert g["checkpoint_heading_error_deg"] == pytest.approx(0.0)
    # facing west (yaw +90 deg), the checkpoint north of us is to the right: turn right, > 0
    g = checkpoint_guidance(NORTH, 0.0, 0.0, 0.0, math.radians(90))
    assert g["checkpoint_heading_error_deg"] == pytest.approx(90.0)
    # a checkpoint to the east: bearing 90, clockwise from north
    east = Path([(0.0, 0.0), (10.0, 0.0)])
    assert checkpoint_guidance(east, 0.0, 0.0, 0.0, 0.0)["checkpoint_bearing_deg"] == pytest.approx(90.0)
    assert checkpoint_guidance(NORTH, 25.0, 0.0, 25.0, 0.0) == {"checkpoint": None}


@pytest.mark.parametrize("controller", ["pure_pursuit", "stanley"])
def test_the_loop_at_3_to_5_mps_within_the_issue_bounds(controller):
    """The 40 m x 24 m loop, speed swinging between 3 and 5 m/s as the sim's person drives:
    finished, cross-track against the truth <= 0.3 m RMS and <= 1 m max, every checkpoint
    passed within 2 m."""
    drive = drive_loop(3.0, 5.0, controller)
    assert (drive.mode, drive.reason) == ("finished", "route end")
    e = np.abs(drive.cross_track_m)
    assert math.sqrt(np.mean(e ** 2)) <= 0.3
    assert e.max() <= 1.0
    assert drive.checkpoint_miss_m.max() <= 2.0
    assert len(e) > 50 * 25                       # it did drive round: 155 m at <= 5 m/s, 50 Hz


@pytest.mark.parametrize("controller", ["pure_pursuit", "stanley"])
@pytest.mark.parametrize("speed_mps", [3.0, 5.0, 8.0])
def test_the_pilot_plans_inside_the_steerings_speed_envelope(controller, speed_mps):
    """Issue 26: every setpoint goes through the steering's own envelope (lateral
    acceleration, jerk and slew by speed); the pilot plans inside the same limits, so the
    envelope limits none of them, and the loop is followed as before it (docs/pilot.md)."""
    drive = drive_loop(speed_mps, speed_mps, controller)
    assert (drive.mode, drive.reason) == ("finished", "route end")
    assert drive.setpoints > 50 * 15 and drive.limited == {}
    e = np.abs(drive.cross_track_m)
    assert math.sqrt(np.mean(e ** 2)) <= 0.25 and e.max() <= 0.6     # 8 m/s before the envelope: 0.21 / 0.51
