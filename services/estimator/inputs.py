"""What the estimator accepts: IMU samples and GNSS fixes, read through their schemas.

The schema modules read a decoded sample into a typed one (`read_sample` in
common/samples/imu.py, `read_fix` in common/samples/fix.py), checking each
field the estimator reads with the schema's own checks; a sample from any source will do
(README, "Estimator"). Here come the estimator's own limits on top: the sensors' ranges, a
position near the Earth, sigmas that mean something, a velocity that is not history. A
rejected input raises `Rejected` with a short reason that the estimator counts under that
name, so that nothing non-finite or absurd ever reaches the filter. Cheap on purpose:
this runs for every IMU sample. numpy numbers and arrays are read as what they hold.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from viena.common.geodesy import plausible_ecef
from viena.common.samples.fix import Fix, read_fix
from viena.common.samples.imu import ImuSample, read_sample
from viena.common.schema import FieldError

STANDARD_GRAVITY = 9.80665


class Rejected(Exception):
    """An input the filter must not see; `reason` is the counter name, `source` the unit
    whose stamp was refused (for refusals for time)."""

    def __init__(self, reason: str, detail: str = "", source: str | None = None):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.source = source


def _read(read, sample):
    """A typed sample, or Rejected: "non_finite" for a NaN or infinity, else "malformed".

    numpy scalars and arrays (what a script's arithmetic makes) are read as the plain
    numbers and lists they hold; only a sample that fails as it is pays for looking."""
    try:
        return read(sample)
    except FieldError as exc:
        plain = _without_numpy(sample)
        if plain is not None:
            return _read(read, plain)
        raise Rejected("non_finite" if exc.not_finite else "malformed", str(exc)) from None


def _without_numpy(sample):
    """The sample with numpy values as Python ones, or None if it has none."""
    if type(sample) is not dict:
        return None
    out, changed = {}, False
    for k, v in sample.items():
        if type(v).__module__ == "numpy":
            v, changed = v.tolist(), True         # a scalar's .tolist() is its Python value
        elif type(v) in (list, tuple) and any(type(x).__module__ == "numpy" for x in v):
            v, changed = [x.tolist() if type(x).__module__ == "numpy" else x for x in v], True
        out[k] = v
    return out if changed else None


@dataclass(frozen=True)
class ImuLimits:
    max_accel_mps2: float = 16.0 * STANDARD_GRAVITY   # the ADXL345's full range
    max_gyro_radps: float = math.radians(2000.0)      # the ITG-3200's full range
    max_mag_T: float = 1e-3                           # 20 x the Earth's field


def imu_sample(sample, limits: ImuLimits) -> ImuSample:
    """The sample, typed and within the sensors' ranges."""
    s = _read(read_sample, sample)
    ax, ay, az = s.accel_mps2
    lim = limits.max_accel_mps2
    if not (-lim <= ax <= lim and -lim <= ay <= lim and -lim <= az <= lim):
        raise Rejected("accel_range", f"beyond {lim / STANDARD_GRAVITY:g} g")
    gx, gy, gz = s.gyro_radps
    lim = limits.max_gyro_radps
    if not (-lim <= gx <= lim and -lim <= gy <= lim and -lim <= gz <= lim):
        raise Rejected("gyro_range")
    m = s.mag_T
    if m is not None:
        lim = limits.max_mag_T
        if not (-lim <= m[0] <= lim and -lim <= m[1] <= lim and -lim <= m[2] <= lim):
            raise Rejected("mag_range")
    return s


#: a velocity older than this is history, not a measurement
MAX_VEL_LATENCY_S = 1.0


def gnss_fix(sample) -> Fix:
    """The fix, typed, without the velocity when that is not a measurement, and, when the
    receiver calls it a solution, a place on Earth with real sigmas."""
    fix = _read(read_fix, sample)
    latency = fix.vel_latency_s
    if not 0.0 <= latency < 1e6:
        raise Rejected("malformed", "vel_latency_s is not a latency")
    if not fix.has_velocity or latency > MAX_VEL_LATENCY_S:
        fix = fix.without_velocity()
    if fix.usable:
        if not plausible_ecef(*fix.ecef_m):
            raise Rejected("position_range", "ECEF position is not near the Earth's surface")
        sigma = fix.enu_sigma_m or fix.ecef_sigma_m
        if min(sigma) <= 0.0 or (fix.vel_sigma_mps is not None and min(fix.vel_sigma_mps) <= 0.0):
            raise Rejected("sigma", "a sigma is zero or negative")
        if fix.vel_ecef_mps is not None and max(map(abs, fix.vel_ecef_mps)) > 100.0:
            raise Rejected("velocity_range", "faster than 100 m/s")
    return fix
