"""Bearing, distance and heading error to a waypoint (docs/estimator.md#waypoint-guidance).

The report measures the bearing from north, the compass heading from north, and steers by
their difference, all mapped to +-180 deg: a positive heading error means the waypoint is
to the right (keep right). We take the bearing and distance on the WGS84 ellipsoid through
pymap3d instead of the report's flat-earth degrees-to-metres ratio (same answer at tens of
metres, right answer further away), and the heading from the estimator's yaw: the project's
yaw is counter-clockwise from north, a compass heading is clockwise, so heading = -yaw.
"""
from __future__ import annotations

import math

import pymap3d


def normalize_deg(angle_deg: float) -> float:
    """Map to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def compass_heading_deg(yaw_rad: float) -> float:
    """Clockwise from true north, +-180 deg, from the ENU counter-clockwise yaw."""
    return normalize_deg(-math.degrees(yaw_rad))


def bearing_distance(lat_deg: float, lon_deg: float, wp_lat_deg: float, wp_lon_deg: float,
                     height_m: float = 0.0) -> tuple[float, float]:
    """(bearing deg from north, clockwise, +-180; horizontal distance m) to the waypoint.

    Both points at the same height: a waypoint is a place on the road, not a point in the sky.
    """
    e, n, _ = pymap3d.geodetic2enu(wp_lat_deg, wp_lon_deg, height_m, lat_deg, lon_deg, height_m)
    e, n = float(e), float(n)
    return normalize_deg(math.degrees(math.atan2(e, n))), math.hypot(e, n)


def heading_error_deg(bearing_deg: float, heading_deg: float) -> float:
    """Bearing minus heading, +-180 deg: positive means turn right."""
    return normalize_deg(bearing_deg - heading_deg)


def waypoint_guidance(lat_deg: float, lon_deg: float, yaw_rad: float,
                      wp_lat_deg: float, wp_lon_deg: float, height_m: float = 0.0) -> dict:
    """The three numbers the state carries about the waypoint."""
    bearing, distance = bearing_distance(lat_deg, lon_deg, wp_lat_deg, wp_lon_deg, height_m)
    return {
        "wp_bearing_deg": bearing,
        "wp_distance_m": distance,
        "wp_heading_error_deg": heading_error_deg(bearing, compass_heading_deg(yaw_rad)),
    }


def waypoint_from(obj) -> tuple[float, float] | None:
    """A waypoint put by a person or a program: {"lat": .., "lon": ..}; {} or
    {"clear": true} clears it. Raises ValueError saying what is wrong."""
    if not isinstance(obj, dict):
        raise ValueError("expected a map like {\"lat\": 38.7369, \"lon\": -9.1395}")
    if not obj or obj.get("clear") is True:
        return None
    unknown = set(obj) - {"lat", "lon"}
    if unknown:
        raise ValueError(f"unknown field {sorted(unknown)[0]!r}: expected lat and lon")
    try:
        lat, lon = obj["lat"], obj["lon"]
    except KeyError as exc:
        raise ValueError(f"missing field {exc.args[0]!r}") from None
    for name, v, lim in (("lat", lat, 90.0), ("lon", lon, 180.0)):
        if type(v) not in (int, float) or not math.isfinite(v) or not -lim <= v <= lim:
            raise ValueError(f"{name} must be a number of degrees within +-{lim:g}, got {v!r}")
    return float(lat), float(lon)
