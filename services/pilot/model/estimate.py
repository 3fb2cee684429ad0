"""What the pilot reads of the estimator's state (viena.estimator.state/2), and nothing more.

The estimator owns its schema; the pilot reads these fields with the schema's own checks
(a `Reader`), so a state from any source is judged the same way, and a malformed one is
an error the service counts, never a pose it steers by.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from viena.common.samples.estimator import STATE

_READ = STATE.reader("t", "mode", "position_valid", "heading_valid", "origin", "enu_m", "yaw_rad",
                     "speed_mps", "sigma_h_m", "lat_deg", "lon_deg", "gnss_kind", "gnss_diff_age_s")


@dataclass(frozen=True)
class Estimate:
    """The car's pose for the pilot: rear-axle centre in the estimator's ENU at `origin`."""
    t_ns: int
    mode: str
    position_valid: bool
    heading_valid: bool
    origin: tuple[float, float, float] | None
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    sigma_h_m: float
    lat_deg: float | None = None
    lon_deg: float | None = None
    #: the GNSS solution the estimate rests on (none, single, sbas, dgps, float, fixed) and
    #: its corrections' age (s); None from an estimator that does not say (before issue 28)
    gnss_kind: str | None = None
    gnss_diff_age_s: float | None = None


def estimate_of(state: dict) -> Estimate:
    """An Estimate from a decoded estimator state; FieldError (a SampleError) if a field
    it needs is missing or malformed."""
    t, mode, pos_ok, head_ok, origin, enu, yaw, speed, sigma_h, lat, lon, kind, diff_age = _READ(state)
    return Estimate(t_ns=t, mode=mode, position_valid=pos_ok, heading_valid=head_ok,
                    origin=None if origin is None else (origin[0], origin[1], origin[2]),
                    x_m=enu[0], y_m=enu[1], yaw_rad=yaw, speed_mps=speed,
                    sigma_h_m=sigma_h if math.isfinite(sigma_h) else math.inf,
                    lat_deg=lat, lon_deg=lon, gnss_kind=kind, gnss_diff_age_s=diff_age)
