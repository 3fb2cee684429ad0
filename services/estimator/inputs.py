"""What the estimator accepts: IMU samples and GNSS fixes as dicts in the agreed schemas.

viena.imu.sample/1 (services/imu/model/sample.py) and viena.gnss.fix/1 (services/gnss/model/fix.py),
only the fields the filter needs, checked here so that nothing non-finite or absurd ever
reaches it. A rejected input raises `Rejected` with a short reason that the estimator
counts under that name. Cheap on purpose: this runs for every IMU sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from viena.common.geodesy import plausible_ecef

STANDARD_GRAVITY = 9.80665


class Rejected(Exception):
    """An input the filter must not see; `reason` is the counter name."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def _vec3(v, name: str) -> tuple[float, float, float]:
    try:
        a, b, c = v
    except (TypeError, ValueError):
        raise Rejected("malformed", f"{name} is not 3 numbers") from None
    for x in (a, b, c):
        tx = type(x)
        if tx is not float and tx is not int:
            raise Rejected("malformed", f"{name} has a {tx.__name__}")
    if a - a == 0.0 and b - b == 0.0 and c - c == 0.0:     # false for nan and inf
        return float(a), float(b), float(c)
    raise Rejected("non_finite", name)


#: int ns UTC between 1980 (the GPS epoch) and 2200, as the schemas' F.time
T_MIN_NS, T_MAX_NS = 315_964_800_000_000_000, 7_258_118_400_000_000_000


def _time(sample) -> int:
    t = sample.get("t") if type(sample) is dict else None
    if type(t) is not int or not T_MIN_NS <= t <= T_MAX_NS:
        raise Rejected("malformed", "t is not an int ns UTC time")
    return t


@dataclass(frozen=True)
class ImuLimits:
    max_accel_mps2: float = 16.0 * STANDARD_GRAVITY   # the ADXL345's full range
    max_gyro_radps: float = math.radians(2000.0)      # the ITG-3200's full range
    max_mag_T: float = 1e-3                           # 20 x the Earth's field


def imu_values(sample, limits: ImuLimits):
    """(t, ax, ay, az, gx, gy, gz, mag) with mag (mx, my, mz) in T or None."""
    t = _time(sample)
    ax, ay, az = _vec3(sample.get("accel_mps2"), "accel_mps2")
    gx, gy, gz = _vec3(sample.get("gyro_radps"), "gyro_radps")
    lim = limits.max_accel_mps2
    if not (-lim <= ax <= lim and -lim <= ay <= lim and -lim <= az <= lim):
        raise Rejected("accel_range", f"beyond {lim / STANDARD_GRAVITY:g} g")
    lim = limits.max_gyro_radps
    if not (-lim <= gx <= lim and -lim <= gy <= lim and -lim <= gz <= lim):
        raise Rejected("gyro_range")
    m = sample.get("mag_T")
    if m is not None:
        m = _vec3(m, "mag_T")
        lim = limits.max_mag_T
        if not (-lim <= m[0] <= lim and -lim <= m[1] <= lim and -lim <= m[2] <= lim):
            raise Rejected("mag_range")
    return t, ax, ay, az, gx, gy, gz, m


class Fix(NamedTuple):
    """The parts of a viena.gnss.fix/1 sample the filter uses, checked."""

    t: int
    unit: str
    usable: bool                 # valid and SOL_COMPUTED
    status: str
    ecef_m: tuple
    ecef_sigma_m: tuple
    vel_ecef_mps: tuple | None   # None when missing or its solution is not computed
    vel_sigma_mps: tuple | None
    vel_latency_s: float


SOL_COMPUTED = "SOL_COMPUTED"
#: a velocity older than this is history, not a measurement
MAX_VEL_LATENCY_S = 1.0


def gnss_fix(sample) -> Fix:
    t = _time(sample)
    unit = sample.get("unit", "gnss")
    valid = sample.get("valid")
    status = sample.get("pos_status", SOL_COMPUTED)
    if type(unit) is not str or type(valid) is not bool or type(status) is not str:
        raise Rejected("malformed", "unit, valid or pos_status has the wrong type")
    ecef = _vec3(sample.get("ecef_m"), "ecef_m")
    sigma = _vec3(sample.get("ecef_sigma_m"), "ecef_sigma_m")
    usable = valid and status == SOL_COMPUTED
    vel = vel_sigma = None
    if sample.get("vel_ecef_mps") is not None:
        vel = _vec3(sample["vel_ecef_mps"], "vel_ecef_mps")
        if sample.get("vel_sigma_mps") is not None:
            vel_sigma = _vec3(sample["vel_sigma_mps"], "vel_sigma_mps")
        vel_status = sample.get("vel_status", SOL_COMPUTED)
        if vel_status != SOL_COMPUTED or sample.get("vel_type") == "NONE":
            vel = vel_sigma = None
    latency = sample.get("vel_latency_s")
    if latency is None:
        latency = 0.0
    elif type(latency) not in (float, int) or not 0.0 <= latency < 1e6:
        raise Rejected("malformed", "vel_latency_s is not a latency")
    elif latency > MAX_VEL_LATENCY_S:
        vel = vel_sigma = None             # the receiver's velocity is stale: not a measurement
    if usable:
        # a solution the receiver calls good must be a place on Earth with real sigmas
        if not plausible_ecef(*ecef):
            raise Rejected("position_range", "ECEF position is not near the Earth's surface")
        if min(sigma) <= 0.0 or (vel_sigma is not None and min(vel_sigma) <= 0.0):
            raise Rejected("sigma", "a sigma is zero or negative")
        if vel is not None and max(abs(v) for v in vel) > 100.0:
            raise Rejected("velocity_range", "faster than 100 m/s")
    return Fix(t, unit, usable, status, ecef, sigma, vel, vel_sigma, float(latency))
