"""When the pilot must not steer: pure decisions on (estimate, where on the path, time).

Each check returns None (fine) or the reason, one line a person reads in `pilot/state`.
The pilot refuses to start, or stops (no more setpoints, then disarm), on any of them;
the steering's own watchdog stays the last line if the pilot itself dies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from viena.common.rotation import wrap_angle
from viena.common.settings import setting
from viena.services.pilot.model.estimate import Estimate
from viena.services.pilot.model.path import Projection

#: estimator modes whose position and heading the pilot may steer by: the normal mode,
#: dead reckoning through a GNSS gap (its sigma says how long that is good for), and GNSS
#: with a constant-velocity model when there is no IMU
STEERABLE_MODES = ("navigating", "coasting", "gnss_only")


@dataclass(frozen=True)
class SafetySettings:
    """When the pilot refuses to start or stops steering."""
    max_estimate_age_s: float = setting(0.2, "an estimate older than this is stale: stop")
    max_sigma_h_m: float = setting(2.5, "the estimate's horizontal 1-sigma above this: stop "
                                        "(single-point GNSS is ~1.8 m; tighten with SBAS or RTK)")
    max_start_offset_m: float = setting(1.5, "refuse to start further than this from the route "
                                             "(less than max_cross_track_m)")
    max_start_heading_deg: float = setting(60.0, "refuse to start facing further than this from the route's way")
    max_cross_track_m: float = setting(2.0, "stop when the car is this far off the route")
    max_route_distance_m: float = setting(1000.0, "refuse a route whose nearest checkpoint is further from the car")


def estimate_problem(est: Estimate | None, now_ns: int, s: SafetySettings) -> str | None:
    """Why this estimate cannot be steered by, if it cannot."""
    if est is None:
        return "no estimate from the estimator"
    age_s = (now_ns - est.t_ns) * 1e-9
    if age_s > s.max_estimate_age_s:
        return f"estimate stale: {age_s * 1e3:.0f} ms old (at most {s.max_estimate_age_s * 1e3:.0f} ms)"
    if est.mode not in STEERABLE_MODES:
        return f"estimate not valid: estimator {est.mode}"
    if not est.position_valid or est.origin is None:
        return "estimate not valid: no position"
    if not est.heading_valid:
        return "estimate not valid: no heading"
    if not math.isfinite(est.sigma_h_m) or est.sigma_h_m > s.max_sigma_h_m:
        return f"estimate too uncertain: sigma {est.sigma_h_m:.2f} m (at most {s.max_sigma_h_m:.2f} m)"
    return None


def start_problem(where: Projection, path_length_m: float, yaw_rad: float, s: SafetySettings) -> str | None:
    """Why the pilot may not start here, if it may not."""
    if abs(where.cross_track_m) > s.max_start_offset_m or where.s_m < -s.max_start_offset_m:
        off = max(abs(where.cross_track_m), -where.s_m)
        return f"too far from the route: {off:.1f} m (at most {s.max_start_offset_m:.1f} m)"
    if where.s_m >= path_length_m:
        return "at the end of the route already"
    heading_deg = math.degrees(abs(wrap_angle(where.path_yaw_rad - yaw_rad)))
    if heading_deg > s.max_start_heading_deg:
        return (f"facing {heading_deg:.0f} deg away from the route's way "
                f"(at most {s.max_start_heading_deg:.0f} deg)")
    return None


def tracking_problem(where: Projection, s: SafetySettings) -> str | None:
    """Why the pilot must stop while following, if it must (the route's end is not a
    problem: see `Pilot`)."""
    if abs(where.cross_track_m) > s.max_cross_track_m:
        return (f"cross-track error {abs(where.cross_track_m):.2f} m "
                f"(at most {s.max_cross_track_m:.2f} m)")
    return None
