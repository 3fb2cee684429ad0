"""A reference station: where it stands and what it measures, epoch by epoch.

The base stands at the sim's origin plus a baseline (a vector in the origin's east, north,
up, or a distance and bearing along the ellipsoid: 0 m to 200 km and more) and observes
the satellites of sky.py above its elevation mask. Each epoch it measures, per satellite
and band, what a geodetic receiver measures:

    pseudorange  P = rho + c (b - dt_sat) + I_f + T + multipath + noise
    phase range  L = rho + c (b - dt_sat) - I_f + T + lambda N + multipath/100 + noise/100

rho is the geometric range from the satellite at transmission to the antenna at
reception (light time iterated, the Earth's rotation during it applied), b the
receiver's clock (steered, tens of nanoseconds), dt_sat the satellite's clock (a fixed
offset and drift per satellite, the same for every base: it is the satellite's), I_f the
ionosphere at frequency f (a vertical delay following the local time of day, mapped by a
thin shell at 350 km), T the troposphere (2.3 m at the zenith, mapped by elevation), N an
integer ambiguity drawn for each pass of a satellite (each new lock), the lock time
counted from the satellite's rise (or the station's start). Noise and multipath grow at
low elevation. Everything is a function of the epoch and the seed, so two calls for one
epoch give the same bytes, whatever came before.
"""
from __future__ import annotations

import functools
import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pymap3d
from pymap3d import vincenty

from viena.common.geodesy import LocalFrame

from . import rtcm, sky

#: the elevation below which the base tracks nothing
MASK_DEG = 10.0
SHELL_HEIGHT_M = 350e3
ZENITH_TROPO_M = 2.3
SYSTEM_CODES = {"GPS": 1, "GLO": 2}
#: satellite id -> its index in the constellation's arrays
_INDEX = {name: {int(s): i for i, s in enumerate(c.ids)} for name, c in sky.CONSTELLATIONS.items()}
_STEP_S = 60.0                      # how far apart a pass is sampled when looking for its rise
_MAX_PASS_S = 8 * 3600.0


@dataclass(frozen=True)
class Observation:
    """One satellite at one epoch, with its measured signals by band (1: L1/G1, 2: L2/G2)."""
    system: str
    sat: int
    elevation_deg: float
    azimuth_deg: float
    range_m: float                  # the geometric range (truth, for tests)
    signals: dict[int, rtcm.Signal] = field(default_factory=dict)

    def rtcm(self) -> rtcm.SatSignals:
        return rtcm.SatSignals(self.sat, self.signals)


@dataclass(frozen=True)
class Epoch:
    """What the base measured at GPS time `gps_s` (seconds since the GPS epoch)."""
    gps_s: float
    sats: tuple[Observation, ...]

    def of(self, system: str) -> list[Observation]:
        return [o for o in self.sats if o.system == system]

    @property
    def tow_ms(self) -> int:
        return round(self.gps_s * 1000) % (604_800 * 1000)


def place(origin: Sequence[float], baseline_m: float = 0.0, bearing_deg: float = 0.0,
          enu_m: Sequence[float] | None = None) -> tuple[float, float, float]:
    """(lat, lon, height) of a point `baseline_m` from `origin` along the ellipsoid at
    `bearing_deg` (clockwise from north), or at `enu_m` in the origin's local frame."""
    lat0, lon0, h0 = (float(v) for v in origin)
    if enu_m is not None:
        lat, lon, h = pymap3d.enu2geodetic(*(float(v) for v in enu_m), lat0, lon0, h0)
        return float(lat), float(lon), float(h)
    if baseline_m < 0:
        raise ValueError(f"a baseline is a distance, not {baseline_m} m")
    if baseline_m == 0:
        return lat0, lon0, h0
    lat, lon = vincenty.vreckon(lat0, lon0, float(baseline_m), float(bearing_deg) % 360.0)
    return float(lat), float(lon) if float(lon) <= 180 else float(lon) - 360.0, h0


@functools.cache
def _sat_clock(system: str, sat: int) -> tuple[float, float]:
    """A satellite's clock offset (s) and drift (s/s): the satellite's own, shared by all bases."""
    rng = np.random.default_rng([SYSTEM_CODES[system], sat, 0x5A7C])
    return float(rng.uniform(-3e-4, 3e-4)), float(rng.uniform(-5e-12, 5e-12))


class BaseStation:
    """A reference station observing GPS (and GLONASS, for MSM) from a fixed antenna."""

    def __init__(self, lat_deg: float, lon_deg: float, height_m: float, station_id: int = 0,
                 seed: int = 0, systems: Sequence[str] = ("GPS", "GLO"), mask_deg: float = MASK_DEG,
                 antenna_height_m: float = 0.0, since_gps_s: float | None = None,
                 descriptors: rtcm.Descriptors = rtcm.DESCRIPTORS):
        if not 0 <= station_id <= 4095:
            raise ValueError(f"a reference station id is 0 to 4095 (DF003), not {station_id}")
        unknown = set(systems) - set(sky.CONSTELLATIONS)
        if unknown:
            raise ValueError(f"unknown satellite systems {sorted(unknown)}: GPS and GLO are known")
        self.position = (float(lat_deg), float(lon_deg), float(height_m))
        self.frame = LocalFrame(*self.position)
        self.ecef_m = np.array(pymap3d.geodetic2ecef(*self.position), float)
        self.station_id = station_id
        self.seed = seed
        self.systems = tuple(systems)
        self.mask_rad = math.radians(mask_deg)
        self.antenna_height_m = antenna_height_m
        self.since_gps_s = since_gps_s
        self.descriptors = descriptors
        rng = np.random.default_rng([seed, zlib.crc32(b"receiver clock")])
        self._clock = (float(rng.uniform(-5e-8, 5e-8)), float(rng.uniform(0, 2 * math.pi)))
        self._rises: dict[tuple[str, int], tuple[float, float]] = {}
        self._ambiguities: dict[tuple, int] = {}

    @classmethod
    def at(cls, origin: Sequence[float], baseline_m: float = 0.0, bearing_deg: float = 0.0,
           enu_m: Sequence[float] | None = None, **kwargs) -> BaseStation:
        """A base at `baseline_m` and `bearing_deg` from `origin` (or at `enu_m` from it)."""
        return cls(*place(origin, baseline_m, bearing_deg, enu_m), **kwargs)

    def baseline_m(self, lat_deg: float, lon_deg: float, height_m: float) -> float:
        """The straight-line distance from this base to a point."""
        return float(np.linalg.norm(np.array(pymap3d.geodetic2ecef(lat_deg, lon_deg, height_m)) - self.ecef_m))

    # -- what it measures ----------------------------------------------------------------------
    def clock_bias_s(self, gps_s: float) -> float:
        """The receiver's clock: steered to GPS time within tens of nanoseconds."""
        b0, phase = self._clock
        return b0 + 2e-8 * math.sin(2 * math.pi * gps_s / 1800.0 + phase)

    def visible(self, system: str, gps_s: float) -> list[tuple[int, float, float]]:
        """(satellite, elevation rad, azimuth rad) of the satellites above the mask."""
        c = sky.CONSTELLATIONS[system]
        el, az = sky.look_angles(self.ecef_m, c.ecef_m(gps_s), self.frame.rot_ecef_to_enu)
        return [(int(s), float(e), float(a)) for s, e, a in zip(c.ids, el, az) if e >= self.mask_rad]

    def observe(self, gps_s: float) -> Epoch:
        """The base's measurements at the epoch `gps_s` (its own clock's reading)."""
        sats = []
        rng = np.random.default_rng([self.seed, round(gps_s * 1000)])        # the epoch's noise
        for system in self.systems:
            for sat, el, az in self.visible(system, gps_s):
                sats.append(self._observe(system, sat, el, az, gps_s, rng.normal(0.0, 1.0, 4)))
        return Epoch(float(gps_s), tuple(sats))

    def _observe(self, system: str, sat: int, el: float, az: float, gps_s: float, noise: np.ndarray) -> Observation:
        c = sky.CONSTELLATIONS[system]
        index = _INDEX[system][sat]
        b = self.clock_bias_s(gps_s)
        rho = self._range(c, index, gps_s - b)
        dt0, drift = _sat_clock(system, sat)
        dt_sat = dt0 + drift * (gps_s % 86400.0 - 43200.0)       # kept in step by daily uploads
        clocks = rtcm.C_MPS * (b - dt_sat)
        tropo = ZENITH_TROPO_M * 1.001 / math.sqrt(0.002001 + math.sin(el) ** 2)
        iono_l1 = self._vertical_iono_m(gps_s) * self._obliquity(el)
        lock_start = self._lock_start(system, sat, gps_s)
        lock_s = gps_s - lock_start
        weak = 1.0 / max(math.sin(el), 0.17)
        freqs = ((rtcm.GPS_L1_HZ, rtcm.GPS_L2_HZ) if system == "GPS" else sky.glonass_frequencies_hz(sat))
        signals = {}
        for band, f in enumerate(freqs, 1):
            lam = rtcm.C_MPS / f
            iono = iono_l1 * (rtcm.GPS_L1_HZ / f) ** 2
            multipath = 0.25 * weak * math.sin(2 * math.pi * gps_s / (300.0 + 37 * sat + 11 * band) + sat)
            ambiguity = self._ambiguity(system, sat, band, lock_start)
            code = rho + clocks + iono + tropo + multipath + 0.15 * math.sqrt(weak) * noise[2 * band - 2]
            phase = (rho + clocks - iono + tropo + lam * ambiguity + multipath / 100
                     + 0.0015 * math.sqrt(weak) * noise[2 * band - 1])
            cnr = 30.0 + 20.0 * math.sqrt(max(math.sin(el), 0.0)) - 6.0 * (band - 1)
            signals[band] = rtcm.Signal(code, phase, lock_s, cnr)
        return Observation(system, sat, math.degrees(el), math.degrees(az), rho, signals)

    def _range(self, c: sky.Constellation, index: int, t_receive: float) -> float:
        """Geometric range: satellite at transmission, antenna at reception, in the ECEF
        frame of reception (the Earth turns by omega_e * tau meanwhile)."""
        tau = 0.075
        for _ in range(3):
            x, y, z = c.sat_ecef_m(index, t_receive - tau)
            turn = sky.OMEGA_E_RADPS * tau
            xr, yr = x * math.cos(turn) + y * math.sin(turn), -x * math.sin(turn) + y * math.cos(turn)
            rho = math.dist((xr, yr, z), self.ecef_m)
            tau = rho / rtcm.C_MPS
        return rho

    def _vertical_iono_m(self, gps_s: float) -> float:
        """L1 vertical delay: 2 m at night, up to 8 m at 14 h local time."""
        local_h = (gps_s / 3600.0 + self.position[1] / 15.0) % 24.0
        return 2.0 + 6.0 * max(0.0, math.cos(2 * math.pi * (local_h - 14.0) / 24.0))

    @staticmethod
    def _obliquity(el: float) -> float:
        s = sky.EARTH_RADIUS_M * math.cos(el) / (sky.EARTH_RADIUS_M + SHELL_HEIGHT_M)
        return 1.0 / math.sqrt(1.0 - s * s)

    def _ambiguity(self, system: str, sat: int, band: int, lock_start: float) -> int:
        key = (system, sat, band, round(lock_start))
        found = self._ambiguities.get(key)
        if found is None:
            if len(self._ambiguities) > 512:
                self._ambiguities.clear()
            rng = np.random.default_rng([self.seed, SYSTEM_CODES[system], sat, band, key[3]])
            found = self._ambiguities[key] = int(rng.integers(-400, 401))
        return found

    # -- lock: since the satellite rose (or the station started) ----------------------------------
    def _lock_start(self, system: str, sat: int, gps_s: float) -> float:
        rise = self._rise(system, sat, gps_s)
        return rise if self.since_gps_s is None else max(rise, self.since_gps_s)

    def _rise(self, system: str, sat: int, gps_s: float) -> float:
        """When the pass in which `sat` is seen at `gps_s` rose above the mask; cached for
        the pass (a satellite seen less than a minute apart is on the same pass)."""
        key = (system, sat)
        cached = self._rises.get(key)
        if cached is not None and cached[0] <= gps_s and 0 <= gps_s - cached[1] <= _STEP_S:
            self._rises[key] = (cached[0], gps_s)
            return cached[0]
        c = sky.CONSTELLATIONS[system]
        index = _INDEX[system][sat]
        times = gps_s - np.arange(0.0, _MAX_PASS_S + _STEP_S, _STEP_S)
        el, _ = sky.look_angles(self.ecef_m, c.ecef_m(times)[index], self.frame.rot_ecef_to_enu)
        below = np.flatnonzero(el < self.mask_rad)
        if not below.size:
            rise = float(times[-1])
        else:
            lo, hi = float(times[below[0]]), float(times[below[0] - 1]) if below[0] else gps_s
            for _ in range(30):                      # to a few microseconds
                mid = (lo + hi) / 2
                e, _ = sky.look_angles(self.ecef_m, c.ecef_m(mid)[index], self.frame.rot_ecef_to_enu)
                lo, hi = (mid, hi) if e < self.mask_rad else (lo, mid)
            rise = hi
        self._rises[key] = (rise, gps_s)
        return rise
