"""The estimate as a sample: viena.estimator.state/1, built from the estimator's parts.

`build_state` reads the filters and says what the estimator is doing (`mode`); it also
returns the sample's floats, so that the caller can check them all for a NaN at once
(a sum of floats is finite if and only if they all are).
"""
from __future__ import annotations

import math

from viena.services.estimator.heading import UNKNOWN_VAR
from viena.services.estimator.kalman import NavKalman
from viena.services.estimator.navigation import waypoint_guidance

#: a valid schema time for a state before any input (1980-01-06, the GPS epoch)
TIME_FLOOR_NS = 315_964_800_000_000_000


def mode(est) -> str:
    t = est.timeline.t_state
    if t is None:
        return "waiting"
    if not est.timeline.imu_live:
        return "gnss_only" if est.kf.initialized else "waiting"
    if not est.attitude.aligned:
        return "aligning"
    if not est.kf.initialized:
        return "attitude"
    timeout = est.gnss_timeout_ns
    gnss = any(t - tf < timeout for tf in est.gnss.last_fix_t.values())
    return "navigating" if gnss else "coasting"


def build_state(est, seq: int) -> tuple[dict, list]:
    """The sample, and its floats."""
    kf = est.kf
    att = est.attitude
    counters = est.counters
    if kf.initialized:
        x = kf.x
        d = kf.P.diagonal().tolist()      # as of the last update or covariance step
        pos, vel, bias, pos_var, vel_var = x[0:3], x[3:6], x[6:9], d[0:3], d[3:6]
    else:
        pos = vel = bias = [0.0, 0.0, 0.0]
        pos_var = vel_var = [NavKalman.MAX_POS_VAR] * 3
    w, qx, qy, qz = q = att.att.q
    yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * qy - qz * qx))))
    roll = math.atan2(2 * (w * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
    t = est.timeline.t_state or TIME_FLOOR_NS
    frame = est.frame
    geo = (None, None, None)
    if frame is not None and kf.initialized:
        geo = frame.geodetic_of_enu(pos[0], pos[1], pos[2])
    source = est.heading.source
    att_var = [est.heading.yaw_var(), *(est.tilt_var() if att.aligned else (UNKNOWN_VAR,) * 2)]
    out = {
        "t": t,
        "seq": seq,
        "mode": mode(est),
        "aligned": att.aligned,
        "heading_valid": est.heading.valid,
        "heading_source": source,
        "position_valid": kf.initialized,
        "imu_live": est.timeline.imu_live,
        "gnss_live": est.gnss.live_units(t, est.gnss_timeout_ns),
        "origin": list(frame.origin) if frame else None,
        "origin_source": est.origin_source,
        "enu_m": list(pos),
        "enu_var_m2": pos_var,
        "lat_deg": geo[0], "lon_deg": geo[1], "height_m": geo[2],
        "vel_enu_mps": list(vel),
        "vel_var_m2ps2": vel_var,
        "speed_mps": math.hypot(vel[0], vel[1]),
        "quat": list(q),
        "yaw_rad": yaw, "pitch_rad": pitch, "roll_rad": roll,
        "att_var_rad2": att_var,
        "rate_body_radps": list(att.rate),
        "accel_bias_mps2": list(bias),
        "gyro_bias_radps": list(att.gyro_bias),
        "gnss_used": counters.gnss_used,
        "gnss_rejected": dict(counters.gnss_rejected),
        "input_rejected": dict(counters.input_rejected),
        "counts": dict(counters.counts),
        "last_reset": counters.last_reset,
        "waypoint": list(est.waypoint) if est.waypoint else None,
        "wp_bearing_deg": None, "wp_distance_m": None, "wp_heading_error_deg": None,
    }
    if est.waypoint and geo[0] is not None:
        out.update(waypoint_guidance(geo[0], geo[1], yaw, *est.waypoint, geo[2]))
    numbers = [*pos, *vel, *bias, *pos_var, *vel_var, *q, *att_var, *att.rate, *att.gyro_bias]
    if geo[0] is not None:
        numbers += geo
    return out, numbers
