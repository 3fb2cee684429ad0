"""The Titans' geo values to the next checkpoint (`checkpoint_guidance`, docs/pilot.md#keys-and-state),
from a route given in degrees as a person sends it: bearing from north, clockwise, ±180;
distance on the ground; heading error = bearing - compass heading, ±180, > 0: turn right.
Checked against the Titans report's own flat-earth method at short range and against
pymap3d on the ellipsoid when the car is far from the estimator's ENU origin. (The estimator
checked these for one target point until issue 17 moved route logic to the pilot.)"""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from viena.services.pilot.model.path import Path
from viena.services.pilot.model.pilot import checkpoint_guidance
from viena.services.pilot.model.route import checked

IST = (38.7369, -9.1395, 100.0)                 # the estimator's ENU origin


def guidance_from(car_lat_lon: tuple[float, float], checkpoint_lat_lon: tuple[float, float],
                  yaw_rad: float = 0.0, origin: tuple[float, float, float] = IST) -> dict:
    """The pilot's values for a car standing at the first point of a two-point route,
    as the pilot works them out: in the estimator's ENU frame at `origin`."""
    path = Path.from_route(checked([car_lat_lon, checkpoint_lat_lon], [None, None], "points"), origin)
    x, y, _ = pymap3d.geodetic2enu(*car_lat_lon, origin[2], *origin)
    x, y = float(x), float(y)
    return checkpoint_guidance(path, path.project(x, y).s_m, x, y, yaw_rad)


def titans_flat_bearing_distance(lat, lon, cp_lat, cp_lon):
    """The report's way: metres per degree at this latitude, the angle to a point north."""
    m_lat = 111_132.92 - 559.82 * math.cos(2 * math.radians(lat))
    m_lon = 111_412.84 * math.cos(math.radians(lat)) - 93.5 * math.cos(3 * math.radians(lat))
    a = np.array([(cp_lon - lon) * m_lon, (cp_lat - lat) * m_lat])
    alpha = math.degrees(math.acos(a @ np.array([0.0, 1.0]) / np.linalg.norm(a)))
    return (alpha if a[0] >= 0 else -alpha), float(np.linalg.norm(a))


@pytest.mark.parametrize("de, dn", [(30, 40), (-30, 40), (-10, -70), (60, -5), (0.0, 120), (-200, 0.1)])
def test_bearing_and_distance_match_the_titans_method_at_short_range(de, dn):
    checkpoint = pymap3d.enu2geodetic(de, dn, 0.0, *IST)[:2]
    g = guidance_from(IST[:2], checkpoint)
    t_bearing, t_distance = titans_flat_bearing_distance(*IST[:2], *checkpoint)
    assert g["checkpoint"] == 1
    assert g["checkpoint_bearing_deg"] == pytest.approx(math.degrees(math.atan2(de, dn)), abs=0.01)
    assert g["checkpoint_bearing_deg"] == pytest.approx(t_bearing, abs=0.05)
    assert g["checkpoint_distance_m"] == pytest.approx(math.hypot(de, dn), rel=1e-4)
    assert g["checkpoint_distance_m"] == pytest.approx(t_distance, rel=2e-3)


def test_bearing_and_distance_agree_with_pymap3d_far_from_the_origin():
    """The car 3 km from where the estimator's frame was set up, the checkpoint 900 m away:
    the ENU plane's north is still true north at the car to a few hundredths of a degree."""
    car = pymap3d.enu2geodetic(2400.0, 1800.0, 0.0, *IST)[:2]
    checkpoint = pymap3d.enu2geodetic(600.0, 650.0, 0.0, *car, IST[2])[:2]
    g = guidance_from(car, checkpoint)
    az, _, rng = pymap3d.geodetic2aer(*checkpoint, IST[2], *car, IST[2])
    assert g["checkpoint_bearing_deg"] == pytest.approx(float(az), abs=0.05)
    assert g["checkpoint_distance_m"] == pytest.approx(float(rng), rel=1e-3)


def test_heading_error_says_which_way_to_turn():
    north_east = pymap3d.enu2geodetic(50.0, 50.0, 0.0, *IST)[:2]
    g = guidance_from(IST[:2], north_east, 0.0)                       # facing north
    assert g["checkpoint_bearing_deg"] == pytest.approx(45.0, abs=0.01)
    assert g["checkpoint_heading_error_deg"] == pytest.approx(45.0, abs=0.01)          # turn right
    g = guidance_from(IST[:2], north_east, math.radians(-90))         # facing east
    assert g["checkpoint_heading_error_deg"] == pytest.approx(-45.0, abs=0.01)         # turn left
    g = guidance_from(IST[:2], north_east, math.radians(170))         # facing south-south-west
    assert g["checkpoint_heading_error_deg"] == pytest.approx(-145.0, abs=0.01)


def test_the_compass_heading_is_minus_the_yaw():
    """bearing - heading error is the car's compass heading: yaw +90 deg (CCW) faces West."""
    north = pymap3d.enu2geodetic(0.0, 50.0, 0.0, *IST)[:2]
    for yaw_rad, heading_deg in ((math.pi / 2, -90.0), (-math.pi / 2, 90.0), (0.0, 0.0)):
        g = guidance_from(IST[:2], north, yaw_rad)
        assert g["checkpoint_bearing_deg"] - g["checkpoint_heading_error_deg"] == pytest.approx(heading_deg, abs=0.01)


@settings(max_examples=200, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-50.0, 50.0), st.floats(-50.0, 50.0),
       st.floats(-1e3, 1e3))
def test_bearing_and_heading_error_stay_within_plus_minus_180(way_rad, x_m, y_m, yaw_rad):
    """Any car position and yaw (any number of turns): both in [-180, 180), and the heading
    error is bearing - (-yaw) up to whole turns."""
    ahead = (x_m - 30.0 * math.sin(way_rad), y_m + 30.0 * math.cos(way_rad))
    path = Path([(x_m, y_m), ahead])
    g = checkpoint_guidance(path, 0.0, x_m, y_m, yaw_rad)
    bearing, error = g["checkpoint_bearing_deg"], g["checkpoint_heading_error_deg"]
    assert -180.0 <= bearing < 180.0 and -180.0 <= error < 180.0
    b = math.radians(bearing)                                  # clockwise: the way's yaw negated
    assert (math.cos(b), math.sin(b)) == pytest.approx((math.cos(way_rad), -math.sin(way_rad)), abs=1e-9)
    e, turned = math.radians(error), b + yaw_rad               # bearing - heading, heading = -yaw
    assert (math.cos(e), math.sin(e)) == pytest.approx((math.cos(turned), math.sin(turned)), abs=1e-6)
