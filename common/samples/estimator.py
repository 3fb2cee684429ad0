"""viena.estimator.state/2: the car's estimated state, on viena/<car>/estimator/state.

SI units, angles in rad. Frames (docs/frames.md): positions and velocities in the local
ENU frame at `origin`, attitude body -> ENU (body x right, y forward, z up), yaw about
up (counter-clockwise from north), pitch about the right axis (nose up > 0), roll about
the forward axis (right side down > 0), in the aircraft order yaw, pitch, roll:
R = Rz(yaw) Rx(pitch) Ry(roll) (services/estimator/angles.py).

Version 2 (issue 13): roll and pitch are named by the axes they turn about (in /1
`pitch_rad` turned about forward and `roll_rad` about right, Z-Y-X), and the position's
uncertainty comes as the full covariance, per axis, horizontally and vertically.

Still version 2 after issue 17 took out the four optional fields of guidance to one
target point: routes, and the distance, bearing and heading error to the next checkpoint,
are the pilot's (viena.pilot.state/1). Removing optional fields keeps both sides reading
each other: a reader of the older /2 takes a state without them (an optional field may be
missing), and this schema decodes an older state with them (decoding keeps unknown
fields), so the name stays (docs/dataflow.md#samples). Issue 28 added three optional
fields the same way: the solution kind the estimate rests on, its corrections' age, and
each receiver's kind.
"""
from __future__ import annotations

import math

from viena.common.display import fmt_deg, fmt_num, fmt_unit, fmt_vec, number, vector
from viena.common.schema import F, Schema

MODES = ("waiting", "aligning", "attitude", "navigating", "coasting", "gnss_only")
HEADING_SOURCES = ("none", "mag", "course", "mag+course")
ORIGIN_SOURCES = ("none", "config", "first_fix")
#: chi-square for 2 degrees of freedom, 95 %: the 95 % horizontal ellipse is this many
#: sigma^2 (its semi-major axis 2.45 sigma_h_m)
CHI2_2D_95 = 5.991

STATE = Schema("viena.estimator.state/2", {
    "t": F.time,                          # time the state refers to (last input used), ns UTC
    "seq": F.int,
    # what the estimator is doing
    "mode": F.enum(*MODES),               # see MODES_HELP
    "aligned": F.bool,                    # roll and pitch known (IMU aligned)
    "heading_valid": F.bool,              # yaw known
    "heading_source": F.enum(*HEADING_SOURCES),
    "position_valid": F.bool,             # position and velocity initialised from GNSS
    "standstill": F.bool,                 # the car stands (zero-velocity updates, gyro bias)
    "imu_live": F.bool,
    "gnss_live": F.list(F.str),           # GNSS units heard from lately
    # where
    "origin": F.optional(F.vec(3)),       # [lat_deg, lon_deg, height_m] of the ENU origin
    "origin_source": F.enum(*ORIGIN_SOURCES),
    "enu_m": F.vec(3),
    "enu_var_m2": F.vec(3),               # diagonal of the position covariance
    "enu_cov_m2": F.vec(6),               # the covariance: [ee, en, eu, nn, nu, uu]
    "enu_sigma_m": F.vec(3),              # per axis: sqrt of enu_var_m2
    "sigma_h_m": F.float,                 # semi-major axis of the horizontal 1-sigma ellipse
    "sigma_v_m": F.float,                 # vertical
    "lat_deg": F.optional(F.float),
    "lon_deg": F.optional(F.float),
    "height_m": F.optional(F.float),      # ellipsoidal
    "vel_enu_mps": F.vec(3),
    "vel_var_m2ps2": F.vec(3),
    "speed_mps": F.float,                 # horizontal
    # attitude
    "quat": F.vec(4),                     # body -> ENU, Hamilton, [w, x, y, z]
    "yaw_rad": F.float,                   # about up, CCW from north: the forward axis's heading
    "pitch_rad": F.float,                 # about the right axis (x): nose up > 0
    "roll_rad": F.float,                  # about the forward axis (y): right side down > 0
    "att_var_rad2": F.vec(3),             # [yaw, pitch, roll]
    "rate_body_radps": F.vec(3),          # bias-corrected gyro
    "accel_bias_mps2": F.vec(3),          # body axes
    "gyro_bias_radps": F.vec(3),
    # bookkeeping
    "gnss_used": F.int,
    "gnss_rejected": F.map,               # reason -> count
    "input_rejected": F.map,              # reason -> count (bad or late input)
    "time_refused": F.optional(F.map),    # source (unit) -> inputs refused for their stamp
    "counts": F.map,                      # imu, gnss, imu_gaps, resets, ...
    "last_reset": F.optional(F.str),      # why the filter last reset itself
    "imu_time_offset_hint_s": F.optional(F.float),  # the IMU's time_offset_s the fixes point at
    # how the filter judges its sources and itself (issue 25; optional: older states lack them)
    "imu_mount_hint_deg": F.optional(F.vec(2)),     # [yaw, pitch] of the car's forward axis in the IMU's
    "nis": F.optional(F.map),             # kind -> recent NIS per dimension (1 when consistent)
    "test_ratio": F.optional(F.map),      # kind -> last NIS over the gate (> 1: refused)
    "process_noise_scale": F.optional(F.float),     # the adaptive process noise's factor
    "gnss_admission": F.optional(F.map),  # receiver -> "in use", "probation" or "failing <check>"
    # the solution it rests on (issue 28; optional: older states lack them): the best kind
    # (common/samples/fix.py SOLUTION_KINDS: none, single, sbas, dgps, float, fixed) among
    # the receivers whose fixes went in within gnss_timeout_s, and the age of its corrections now
    "gnss_kind": F.optional(F.str),
    "gnss_diff_age_s": F.optional(F.float),
    "gnss_kinds": F.optional(F.map),      # receiver -> the kind of its last fix that went in
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
    sigma_h, sigma_v = number(state.get("sigma_h_m")), number(state.get("sigma_v_m"))
    if sigma_h is None and var is not None:       # an older state: from the diagonal
        sigma_h, sigma_v = math.sqrt(max(var[0], var[1], 0)), math.sqrt(max(var[2], 0))
    cells = {
        "mode": str(state.get("mode", "-")),
        "position ENU m": fmt_vec(state.get("enu_m")),
        "σ pos": "-" if sigma_h is None else f"{sigma_h:.2f} m",
        "σ h/v": "-" if sigma_h is None or sigma_v is None else f"{sigma_h:.2f} / {sigma_v:.2f} m",
        "speed": fmt_unit(state.get("speed_mps"), "m/s"),
        "yaw": fmt_deg(state.get("yaw_rad")) + yaw_sigma,
        "pitch / roll": f"{fmt_deg(state.get('pitch_rad'))} / {fmt_deg(state.get('roll_rad'))}",
        "heading": f"{state.get('heading_source', '-')}"
                   + ("" if state.get("heading_valid") is not False else " (not valid)"),
        "gnss used": fmt_num(state.get("gnss_used")),
    }
    refused = state.get("time_refused")
    if isinstance(refused, dict) and refused:       # a source sending bad stamps (issue 15)
        cells["refused for time"] = ", ".join(f"{k} {v}" for k, v in sorted(refused.items(), key=str))
    nis = state.get("nis")
    if isinstance(nis, dict) and any(number(v) is not None for v in nis.values()):
        cells["NIS pos/vel/course"] = "/".join(fmt_num(nis.get(k), 1) for k in ("position", "velocity", "course"))
    kind = state.get("gnss_kind")
    if isinstance(kind, str) and kind not in ("none", "single"):   # corrections: which, how old
        age = number(state.get("gnss_diff_age_s"))
        cells["solution"] = kind + ("" if age is None else f", corrections {age:.1f} s old")
    admission = state.get("gnss_admission")
    if isinstance(admission, dict) and any(v != "in use" for v in admission.values()):
        cells["receivers"] = ", ".join(f"{k} {v}" for k, v in sorted(admission.items(), key=str))
    mount = vector(state.get("imu_mount_hint_deg"), 2)
    if mount is not None and max(abs(mount[0]), abs(mount[1])) >= 1.0:
        cells["IMU mount"] = f"yaw {mount[0]:+.1f}° pitch {mount[1]:+.1f}° against the car"
    hint = number(state.get("imu_time_offset_hint_s"))
    if hint is not None:
        cells["IMU clock"] = (f"stamps {abs(hint) * 1e3:.0f} ms {'late' if hint < 0 else 'early'}: "
                              f"time_offset_s = {hint:+.3f}?")
    return cells
