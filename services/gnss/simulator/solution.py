"""A simulated receiver's navigation solution at one epoch, from truth or from a recording.

Both twins (NovAtel and NMEA) turn a `Solution` into their own bytes, so what a receiver
computes is written once: `TruthSolver` adds the error model to the simulated car's truth
at the antenna's lever arm, with the sigmas the model says the receiver reports at that
epoch; the drive replay (replay.py) reads the car's 2016 recording.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pymap3d

from viena.services.gnss.driver.novatel.enums import PositionType, SolutionStatus

from .errors import GnssErrorModel, SkyModel
from .rover import Rover

#: The receiver's position when it has none (seen in the car's data).
NO_FIX_ECEF = (100.0, 0.0, 0.0)
#: Latency of an instantaneous Doppler velocity (BESTVEL, docs/sensors.md#logs-used): always 0.15 s.
DOPPLER_LATENCY_S = 0.15
#: How long a receiver keeps reporting its last fix (INSUFFICIENT_OBS, growing sol_age)
#: before it falls back to the no-fix position; the longest hold in the 2016 drive is 3.1 s.
HOLD_LIMIT_S = 3.5


@dataclass(frozen=True)
class Solution:
    """One epoch of a receiver's solution, in NovAtel's terms (what BESTXYZ carries)."""

    gps_ms: int                         # epoch: milliseconds since the GPS epoch
    pos_status: SolutionStatus
    pos_type: PositionType
    ecef_m: tuple
    ecef_sigma_m: tuple
    vel_status: SolutionStatus
    vel_type: PositionType
    vel_ecef_mps: tuple
    vel_sigma_mps: tuple
    vel_latency_s: float = DOPPLER_LATENCY_S
    diff_age_s: float = 0.0
    sol_age_s: float = 0.0
    sats_tracked: int = 0
    sats_used: int = 0
    undulation_m: float = 0.0           # geoid above ellipsoid, for BESTPOS and GGA
    sigma_enu_m: tuple | None = None    # the position sigmas along E, N, U, when known
    station_id: str = ""                # the differential base's ID (stn id)
    sats_l1_rtk: int = 0                # satellites above the RTK mask, L1 ...
    sats_l2_rtk: int = 0                # ... and L2
    _geodetic: tuple[float, float, float] | None = field(default=None, compare=False, repr=False)

    @property
    def has_fix(self) -> bool:
        return self.pos_status == SolutionStatus.SOL_COMPUTED

    def geodetic(self) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, ellipsoidal height m)."""
        geodetic = self._geodetic
        if geodetic is None:
            lat, lon, h = pymap3d.ecef2geodetic(*self.ecef_m)
            geodetic = (float(lat), float(lon), float(h))
            object.__setattr__(self, "_geodetic", geodetic)
        return geodetic

    def enu_sigma(self) -> tuple[float, float, float]:
        """Position sigmas along E, N, U (from the ECEF ones when not given)."""
        if self.sigma_enu_m is not None:
            return self.sigma_enu_m
        lat, lon, _ = self.geodetic()
        r = _enu_axes(lat, lon)
        cov = r.T @ np.diag(np.square(self.ecef_sigma_m)) @ r
        e, n, u = np.sqrt(np.diag(cov))
        return float(e), float(n), float(u)

    def enu_velocity(self) -> tuple[float, float, float]:
        lat, lon, _ = self.geodetic()
        e, n, u = pymap3d.uvw2enu(*self.vel_ecef_mps, lat, lon)
        return float(e), float(n), float(u)


def _enu_axes(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Columns: the E, N, U unit vectors in ECEF."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    return np.array([[-sl, -sp * cl, cp * cl], [cl, -sp * sl, cp * sl], [0.0, cp, sp]])


@functools.lru_cache(maxsize=64)
def _sigma_ecef_of(sigma_enu: tuple, lat_deg: float, lon_deg: float) -> tuple:
    """Per-axis ECEF sigmas of per-axis ENU ones (a tuple of floats). Remembered: a receiver's
    sigmas and the origin stay the same from epoch to epoch, and the matrix products cost more
    than the rest of an epoch's arithmetic."""
    r = _enu_axes(lat_deg, lon_deg)
    cov = r @ np.diag(np.square(sigma_enu)) @ r.T
    return tuple(float(v) for v in np.sqrt(np.diag(cov)))


class TruthSolver:
    """Solutions from the simulated car's truth at an antenna's lever arm (body frame).

    ``solve(gps_ms, utc_ns)`` must be called with non-decreasing epochs; the truth is
    moved to the epoch with its own velocity (it is at most one sim step old), and the
    velocity is reported as the receiver measures it: as of its latency before the epoch.
    """

    def __init__(self, truth: Callable, lever_arm_m=(0.0, 0.0, 0.0), *,
                 errors: GnssErrorModel, sky: SkyModel, undulation_m: float = 0.0,
                 hold_limit_s: float = HOLD_LIMIT_S):
        self.truth = truth
        self.lever_arm_m = np.asarray(lever_arm_m, float)
        self.errors = errors
        self.sky = sky
        self.undulation_m = undulation_m
        self.hold_limit_s = hold_limit_s
        self.pos_type = PositionType.SINGLE
        self.rover: Rover | None = None     # the corrections' side, when the receiver takes them
        self._t0_ms: int | None = None
        self._last_fix: Solution | None = None
        self.no_fix_until_ms = -1       # cold start: no fix before this epoch

    def cold_start(self, until_ms: int) -> None:
        """After a reset: nothing known, no fix before ``until_ms`` (GPS ms)."""
        self._last_fix = None
        self.no_fix_until_ms = until_ms

    def solve(self, gps_ms: int, utc_ns: int) -> Solution:
        if self._t0_ms is None:
            self._t0_ms = gps_ms
        t_s = (gps_ms - self._t0_ms) / 1000.0
        truth = self.truth()
        err_pos, err_vel = self.errors.step(t_s, gps_ms, sky=self.sky, speed_mps=truth.speed_mps)
        sky = self.sky.at(t_s)
        rover = self.rover
        if sky.outage or gps_ms < self.no_fix_until_ms:
            if rover is not None:
                rover.lose_lock(gps_ms)
            return self._no_fix(gps_ms, sky)
        dt = max(-0.2, min(0.2, (utc_ns - truth.t_ns) / 1e9))
        # 3-vectors as floats from here: element by element the same IEEE operations numpy
        # would do (so the same bits), at a fraction of the cost of numpy on tiny arrays
        frame = truth.frame
        vel_enu = truth.vel_enu_floats_of(self.lever_arm_m)
        enu = [p + v * dt for p, v in zip(truth.enu_floats_of(self.lever_arm_m), vel_enu)]
        antenna = frame.ecef_of_enu(*enu)
        diff = None if rover is None else rover.solve(gps_ms, antenna, err_pos)
        if diff is not None:
            err_pos = diff.error_enu_m
        ecef = [p + e for p, e in zip(antenna, frame.vector_of_enu(*err_pos.tolist()))]
        # a Doppler velocity is DOPPLER_LATENCY_S old at its time tag (vol. 2, BESTVEL:
        # "subtract from the time"), so it is the velocity of that earlier instant
        lag = dt - DOPPLER_LATENCY_S
        vel_then = [v + a * lag for v, a in zip(vel_enu, truth.floats("accel_enu_mps2"))]
        vel = frame.vector_of_enu(*(v + e for v, e in zip(vel_then, err_vel.tolist())))
        lat0, lon0, _ = truth.origin
        sigma_enu = tuple(self.errors.sigma_enu.tolist()) if diff is None else diff.sigma_enu_m
        sol = Solution(
            gps_ms, SolutionStatus.SOL_COMPUTED, self.pos_type if diff is None else diff.pos_type, tuple(ecef),
            _sigma_ecef_of(sigma_enu, float(lat0), float(lon0)), SolutionStatus.SOL_COMPUTED,
            PositionType.DOPPLER_VELOCITY, vel,
            _sigma_ecef_of(tuple(self.errors.velocity_sigma.tolist()), float(lat0), float(lon0)),
            sats_tracked=sky.sats_tracked, sats_used=sky.sats_used,
            undulation_m=self.undulation_m, sigma_enu_m=sigma_enu,
            **({} if diff is None else self._differential_fields(diff, sky.sats_used)))
        self._last_fix = sol
        return sol

    @staticmethod
    def _differential_fields(diff, sats_used: int) -> dict:
        """A differential solution's age and base, and its satellites above the RTK mask
        (L2 too for the narrow-lane types: RT-2 on L1/L2 observables)."""
        l1 = sats_used if diff.rtk else 0
        l2 = l1 if diff.pos_type in (PositionType.NARROW_FLOAT, PositionType.NARROW_INT) else 0
        return dict(diff_age_s=diff.diff_age_s, station_id=diff.station_id, sats_l1_rtk=l1, sats_l2_rtk=l2)

    def _no_fix(self, gps_ms: int, sky) -> Solution:
        """INSUFFICIENT_OBS: the last fix held with its age growing, then X=100, Y=Z=0."""
        last = self._last_fix
        age = math.inf if last is None else (gps_ms - last.gps_ms) / 1000.0
        insufficient = SolutionStatus.INSUFFICIENT_OBS
        if last is not None and age <= self.hold_limit_s:
            return Solution(
                gps_ms, insufficient, PositionType.NONE, last.ecef_m, last.ecef_sigma_m,
                insufficient, PositionType.NONE, last.vel_ecef_mps, last.vel_sigma_mps,
                vel_latency_s=DOPPLER_LATENCY_S + age, sol_age_s=age,
                sats_tracked=sky.sats_tracked, sats_used=sky.sats_used,
                undulation_m=self.undulation_m, sigma_enu_m=last.sigma_enu_m)
        zeros = (0.0, 0.0, 0.0)
        return Solution(gps_ms, insufficient, PositionType.NONE, NO_FIX_ECEF, zeros,
                        insufficient, PositionType.NONE, zeros, zeros, vel_latency_s=0.0,
                        sats_tracked=sky.sats_tracked, sats_used=sky.sats_used,
                        undulation_m=self.undulation_m)
