"""viena.estimator.state/1: the car's estimated state, on viena/<car>/estimator/state.

SI units, angles in rad except the waypoint guidance, which keeps the Titans report's
degrees (as its name says). Frames per design §5: positions and velocities in the local
ENU frame at `origin`, attitude body -> ENU (body x right, y forward, z up), Euler Z-Y-X
as seed eq. 5.4 (yaw about up, pitch about the body's forward y axis, roll about its
right x axis), yaw counter-clockwise from north.
"""
from __future__ import annotations

import math

from viena.common.display import fmt_deg, fmt_num, fmt_unit, fmt_vec, vector
from viena.common.schema import F, Schema

MODES = ("waiting", "aligning", "attitude", "navigating", "coasting", "gnss_only")
HEADING_SOURCES = ("none", "mag", "course", "mag+course")
ORIGIN_SOURCES = ("none", "config", "first_fix")

STATE = Schema("viena.estimator.state/1", {
    "t": F.time,                          # time the state refers to (last input used), ns UTC
    "seq": F.int,
    # what the estimator is doing
    "mode": F.enum(*MODES),               # see MODES_HELP
    "aligned": F.bool,                    # roll and pitch known (IMU aligned)
    "heading_valid": F.bool,              # yaw known
    "heading_source": F.enum(*HEADING_SOURCES),
    "position_valid": F.bool,             # position and velocity initialised from GNSS
    "imu_live": F.bool,
    "gnss_live": F.list(F.str),           # GNSS units heard from lately
    # where
    "origin": F.optional(F.vec(3)),       # [lat_deg, lon_deg, height_m] of the ENU origin
    "origin_source": F.enum(*ORIGIN_SOURCES),
    "enu_m": F.vec(3),
    "enu_var_m2": F.vec(3),               # diagonal of the position covariance
    "lat_deg": F.optional(F.float),
    "lon_deg": F.optional(F.float),
    "height_m": F.optional(F.float),      # ellipsoidal
    "vel_enu_mps": F.vec(3),
    "vel_var_m2ps2": F.vec(3),
    "speed_mps": F.float,                 # horizontal
    # attitude
    "quat": F.vec(4),                     # body -> ENU, Hamilton, [w, x, y, z]
    "yaw_rad": F.float,
    "pitch_rad": F.float,
    "roll_rad": F.float,
    "att_var_rad2": F.vec(3),             # [yaw, pitch, roll], see README
    "rate_body_radps": F.vec(3),          # bias-corrected gyro
    "accel_bias_mps2": F.vec(3),          # body axes
    "gyro_bias_radps": F.vec(3),
    # bookkeeping
    "gnss_used": F.int,
    "gnss_rejected": F.map,               # reason -> count
    "input_rejected": F.map,              # reason -> count (bad or late input)
    "counts": F.map,                      # imu, gnss, imu_gaps, resets, ...
    "last_reset": F.optional(F.str),      # why the filter last reset itself
    # navigation to a waypoint (Titans report)
    "waypoint": F.optional(F.vec(2)),     # [lat_deg, lon_deg]
    "wp_bearing_deg": F.optional(F.float),          # from north, clockwise, +-180
    "wp_distance_m": F.optional(F.float),
    "wp_heading_error_deg": F.optional(F.float),    # bearing - heading, +-180, >0: turn right
})

MODES_HELP = {
    "waiting": "no IMU sample and no GNSS fix yet",
    "aligning": "gathering IMU samples for the initial roll and pitch",
    "attitude": "attitude only: no usable GNSS fix yet",
    "navigating": "IMU and GNSS: the normal mode",
    "coasting": "IMU only, GNSS lost: position drifts",
    "gnss_only": "no IMU: GNSS with a constant-velocity model",
}


def monitor_view(state: dict) -> dict[str, str]:
    """How the monitor shows an estimator state (any map: what came on the state key)."""
    var = vector(state.get("enu_var_m2"), 3)
    att = vector(state.get("att_var_rad2"), 3)
    yaw_sigma = "" if att is None else f" ± {math.degrees(math.sqrt(max(att[0], 0))):.1f}°"
    cells = {
        "mode": str(state.get("mode", "-")),
        "position ENU m": fmt_vec(state.get("enu_m")),
        "σ pos": "-" if var is None else f"{math.sqrt(max(var[0], 0) + max(var[1], 0)):.2f} m",
        "speed": fmt_unit(state.get("speed_mps"), "m/s"),
        "yaw": fmt_deg(state.get("yaw_rad")) + yaw_sigma,
        "heading": f"{state.get('heading_source', '-')}"
                   + ("" if state.get("heading_valid") is not False else " (not valid)"),
        "gnss used": fmt_num(state.get("gnss_used")),
    }
    if state.get("waypoint") is not None:
        cells["waypoint"] = (f"{fmt_num(state.get('wp_distance_m'), 1)} m at "
                             f"{fmt_num(state.get('wp_bearing_deg'), 1)}°, "
                             f"turn {fmt_num(state.get('wp_heading_error_deg'), 1)}°")
    return cells
