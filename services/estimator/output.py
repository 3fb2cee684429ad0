"""The estimate as a sample: viena.estimator.state/2, built from values the estimator reads.

`build_state` takes a `StateView` (what the Estimator read off its parts, nothing
reached into) and returns the sample and its floats, so that the caller can check them
all for a NaN at once (a sum of floats is finite if and only if they all are). `mode`
says what the estimator is doing.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from viena.common.geodesy import LocalFrame
from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.counters import Counters
from viena.services.estimator.kalman import NavKalman

#: a valid schema time for a state before any input (1980-01-06, the GPS epoch)
TIME_FLOOR_NS = 315_964_800_000_000_000


@dataclass(frozen=True)
class StateView:
    """What a state sample is made of, as the Estimator read it off its parts."""
    t: int                              # the state's time (TIME_FLOOR_NS before any input)
    mode: str
    x: list[float] | None               # the Kalman filter's state, when it has a position
    P: np.ndarray | None                # ... and its covariance
    q: tuple                            # the attitude's quaternion
    att_var: list[float]                # [yaw, pitch, roll] variances (rad^2)
    rate: tuple                         # the bias-corrected gyro
    gyro_bias: list[float]
    aligned: bool
    heading_valid: bool
    heading_source: str
    still: bool
    imu_live: bool
    gnss_live: list[str]
    frame: LocalFrame | None
    origin_source: str
    counters: Counters
    offset_hint_s: float | None
    mount_hint_deg: list[float] | None
    consistency: dict
    admission: dict
    solution: tuple[str, float | None, dict[str, str]]


def mode(t: int | None, imu_live: bool, positioned: bool, aligned: bool,
         last_fix_t: Iterable[int], timeout_ns: int) -> str:
    """What the estimator is doing at state time t."""
    if t is None:
        return "waiting"
    if not imu_live:
        return "gnss_only" if positioned else "waiting"
    if not aligned:
        return "aligning"
    if not positioned:
        return "attitude"
    for tf in last_fix_t:
        if t - tf < timeout_ns:
            return "navigating"
    return "coasting"


def _position(view: StateView):
    """(pos, vel, bias, pos_var, vel_var, the ENU position covariance's six entries)."""
    if view.x is None or view.P is None:
        big = NavKalman.MAX_POS_VAR
        zero = [0.0, 0.0, 0.0]
        return zero, zero, zero, [big] * 3, [big] * 3, (big, 0.0, 0.0, big, 0.0, big)
    x, P = view.x, view.P                 # as of the last update or covariance step
    d = P.diagonal().tolist()
    cov = (float(P[0, 0]), float(P[0, 1]), float(P[0, 2]), float(P[1, 1]), float(P[1, 2]), float(P[2, 2]))
    return x[0:3], x[3:6], x[6:9], d[0:3], d[3:6], cov


def build_state(view: StateView, seq: int) -> tuple[dict, list]:
    """The sample, and its floats."""
    pos, vel, bias, pos_var, vel_var, (ee, en, eu, nn, nu, uu) = _position(view)
    # the horizontal ellipse's semi-major axis: the larger eigenvalue of [[ee, en], [en, nn]]
    half, diff = 0.5 * (ee + nn), 0.5 * (ee - nn)
    sigma_h = math.sqrt(max(0.0, half + math.sqrt(diff * diff + en * en)))
    q = view.q
    yaw, pitch, roll = yaw_pitch_roll(q)
    frame = view.frame
    geo: tuple[float | None, float | None, float | None] = (None, None, None)
    if frame is not None and view.x is not None:
        geo = frame.geodetic_of_enu(pos[0], pos[1], pos[2])
    out = {
        "t": view.t, "seq": seq, "mode": view.mode,
        "aligned": view.aligned, "heading_valid": view.heading_valid, "heading_source": view.heading_source,
        "position_valid": view.x is not None, "standstill": view.still,
        "imu_live": view.imu_live, "gnss_live": view.gnss_live,
        "origin": list(frame.origin) if frame else None, "origin_source": view.origin_source,
        "enu_m": list(pos), "enu_var_m2": pos_var, "enu_cov_m2": [ee, en, eu, nn, nu, uu],
        "enu_sigma_m": [math.sqrt(max(0.0, v)) for v in pos_var],
        "sigma_h_m": sigma_h, "sigma_v_m": math.sqrt(max(0.0, uu)),
        "lat_deg": geo[0], "lon_deg": geo[1], "height_m": geo[2],
        "vel_enu_mps": list(vel), "vel_var_m2ps2": vel_var, "speed_mps": math.hypot(vel[0], vel[1]),
        "quat": list(q), "yaw_rad": yaw, "pitch_rad": pitch, "roll_rad": roll,
        "att_var_rad2": view.att_var, "rate_body_radps": list(view.rate),
        "accel_bias_mps2": list(bias), "gyro_bias_radps": list(view.gyro_bias),
        **_counted(view.counters),
        "imu_time_offset_hint_s": view.offset_hint_s, "imu_mount_hint_deg": view.mount_hint_deg,
        **view.consistency,
        "gnss_admission": view.admission,
    }
    kind, diff_age, kinds = view.solution
    out.update(gnss_kind=kind, gnss_diff_age_s=diff_age, gnss_kinds=kinds)
    numbers = [*pos, *vel, *bias, *pos_var, *vel_var, *q, *view.att_var, *view.rate, *view.gyro_bias,
               ee, en, eu, nn, nu, uu, sigma_h]
    if geo[0] is not None:
        numbers += geo
    return out, numbers


def _counted(counters: Counters) -> dict:
    return {"gnss_used": counters.gnss_used,
            "gnss_rejected": dict(counters.gnss_rejected),
            "input_rejected": dict(counters.input_rejected),
            "time_refused": dict(counters.time_refused),
            "counts": dict(counters.counts),
            "last_reset": counters.last_reset}
