"""The estimate as a sample: viena.estimator.state/2, built from the estimator's parts.

`build_state` reads the filters and says what the estimator is doing (`mode`); it also
returns the sample's floats, so that the caller can check them all for a NaN at once
(a sum of floats is finite if and only if they all are).
"""
from __future__ import annotations

import math

from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.heading import UNKNOWN_VAR
from viena.services.estimator.kalman import NavKalman

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
    for tf in est.gnss.last_fix_t.values():
        if t - tf < timeout:
            return "navigating"
    return "coasting"


def build_state(est, seq: int) -> tuple[dict, list]:
    """The sample, and its floats."""
    kf = est.kf
    att = est.attitude
    counters = est.counters
    if kf.initialized:
        x = kf.x
        P = kf.P                          # as of the last update or covariance step
        d = P.diagonal().tolist()
        pos, vel, bias, pos_var, vel_var = x[0:3], x[3:6], x[6:9], d[0:3], d[3:6]
        ee, en, eu, nn, nu, uu = (float(P[0, 0]), float(P[0, 1]), float(P[0, 2]),
                                  float(P[1, 1]), float(P[1, 2]), float(P[2, 2]))
    else:
        pos = vel = bias = [0.0, 0.0, 0.0]
        pos_var = vel_var = [NavKalman.MAX_POS_VAR] * 3
        ee = nn = uu = NavKalman.MAX_POS_VAR
        en = eu = nu = 0.0
    # the horizontal ellipse's semi-major axis: the larger eigenvalue of [[ee, en], [en, nn]]
    half, diff = 0.5 * (ee + nn), 0.5 * (ee - nn)
    sigma_h = math.sqrt(max(0.0, half + math.sqrt(diff * diff + en * en)))
    q = att.att.q
    yaw, pitch, roll = yaw_pitch_roll(q)
    t = est.timeline.t_state or TIME_FLOOR_NS
    frame = est.frame
    geo = (None, None, None)
    if frame is not None and kf.initialized:
        geo = frame.geodetic_of_enu(pos[0], pos[1], pos[2])
    source = est.heading.source
    # [yaw, pitch (about the right axis), roll (about forward)]
    tilt = est.tilt_var() if att.aligned else (UNKNOWN_VAR, UNKNOWN_VAR)
    att_var = [est.heading.yaw_var(), tilt[1], tilt[0]]
    out = {
        "t": t,
        "seq": seq,
        "mode": mode(est),
        "aligned": att.aligned,
        "heading_valid": est.heading.valid,
        "heading_source": source,
        "position_valid": kf.initialized,
        "standstill": est.standstill.still,
        "imu_live": est.timeline.imu_live,
        "gnss_live": est.gnss.live_units(t, est.gnss_timeout_ns),
        "origin": list(frame.origin) if frame else None,
        "origin_source": est.origin_source,
        "enu_m": list(pos),
        "enu_var_m2": pos_var,
        "enu_cov_m2": [ee, en, eu, nn, nu, uu],
        "enu_sigma_m": [math.sqrt(max(0.0, v)) for v in pos_var],
        "sigma_h_m": sigma_h,
        "sigma_v_m": math.sqrt(max(0.0, uu)),
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
        "time_refused": dict(counters.time_refused),
        "counts": dict(counters.counts),
        "last_reset": counters.last_reset,
        "imu_time_offset_hint_s": est.gnss.timing.offset_s,
        "imu_mount_hint_deg": est.mount.hint_deg(),
        **est.consistency.report(),
        "gnss_admission": est.gnss.admission.report(),
    }
    kind, diff_age, kinds = est.gnss.solution(t, est.gnss_timeout_ns)
    out.update(gnss_kind=kind, gnss_diff_age_s=diff_age, gnss_kinds=kinds)
    numbers = [*pos, *vel, *bias, *pos_var, *vel_var, *q, *att_var, *att.rate, *att.gyro_bias,
               ee, en, eu, nn, nu, uu, sigma_h]
    if geo[0] is not None:
        numbers += geo
    return out, numbers
