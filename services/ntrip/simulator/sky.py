"""Where the satellites are: GPS on its 24-slot almanac geometry, GLONASS on its 24 slots.

Simple but honest: circular orbits, the nominal planes and slots, the nodes regressing
under J2 and the Earth turning under them, so a base sees the satellites rise and set as
it would. GPS follows the baseline 24-slot constellation of the SPS Performance Standard
(table 3.2-1 of the 2008 edition: six planes 60 degrees apart, 55 degrees inclined, each
slot's right ascension of the ascending node and argument of latitude at the defined epoch
1993-07-01 00:00 UTC, when the Greenwich hour angle was 18 h 36 min 14.4 s), at the mean
motion that repeats the ground track every sidereal day, as the constellation is kept
(a semi-major axis of 26,561.7 km from it). GLONASS: three planes 120 degrees apart,
64.8 degrees inclined, eight slots 45 degrees apart in each and 15 degrees of phase
between planes, 25,510 km, each slot with its frequency channel (the antipodal slots
share one). No ephemeris errors and no eccentricity: what a base measures is then honest
geometry, and a test can check a position solved from it.

Times are GPS seconds since the GPS epoch (1980-01-06), as floats.
"""
from __future__ import annotations

import calendar
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from viena.services.gnss.driver.gpstime import GPS_EPOCH_UNIX_S, leap_seconds_at_utc

MU_M3PS2 = 3.986005e14                 # IS-GPS-200
OMEGA_E_RADPS = 7.2921151467e-5        # IS-GPS-200
J2 = 1.08263e-3
EARTH_RADIUS_M = 6378137.0
GLONASS_L1_HZ = 1602.0e6
GLONASS_L1_STEP_HZ = 0.5625e6
GLONASS_L2_HZ = 1246.0e6
GLONASS_L2_STEP_HZ = 0.4375e6

#: the defined epoch of the 24-slot table, GPS seconds (UTC then was GPS - 9 s)
_TABLE_UTC_S = calendar.timegm((1993, 7, 1, 0, 0, 0))
SLOT_EPOCH_GPS_S = float(_TABLE_UTC_S - GPS_EPOCH_UNIX_S + leap_seconds_at_utc(_TABLE_UTC_S * 10**9))
#: the Greenwich hour angle at that epoch, degrees (18 h 36 min 14.4 s)
SLOT_EPOCH_GHA_DEG = (18 + 36 / 60 + 14.4 / 3600) * 15.0

#: slot -> (RAAN deg, argument of latitude deg) at the defined epoch (SPS PS 2008, table 3.2-1)
GPS_SLOTS = {
    "A1": (272.847, 268.126), "A2": (272.847, 161.786), "A3": (272.847, 11.676), "A4": (272.847, 41.806),
    "B1": (332.847, 80.956), "B2": (332.847, 173.336), "B3": (332.847, 309.976), "B4": (332.847, 204.376),
    "C1": (32.847, 111.876), "C2": (32.847, 11.796), "C3": (32.847, 339.666), "C4": (32.847, 241.556),
    "D1": (92.847, 135.226), "D2": (92.847, 265.446), "D3": (92.847, 35.156), "D4": (92.847, 167.356),
    "E1": (152.847, 197.046), "E2": (152.847, 302.596), "E3": (152.847, 66.066), "E4": (152.847, 333.686),
    "F1": (212.847, 238.886), "F2": (212.847, 345.226), "F3": (212.847, 105.206), "F4": (212.847, 135.346),
}
#: which PRN flies in which slot: a fixed assignment (the real one changes with launches)
GPS_PRN_OF_SLOT = {
    "A1": 24, "A2": 31, "A3": 30, "A4": 7, "B1": 16, "B2": 25, "B3": 28, "B4": 12,
    "C1": 29, "C2": 27, "C3": 8, "C4": 17, "D1": 2, "D2": 1, "D3": 6, "D4": 11,
    "E1": 3, "E2": 10, "E3": 5, "E4": 18, "F1": 32, "F2": 26, "F3": 15, "F4": 9,
}
#: GLONASS slot -> frequency channel number (antipodal slots share a channel)
GLONASS_FCN = {1: 1, 2: -4, 3: 5, 4: 6, 5: 1, 6: -4, 7: 5, 8: 6, 9: -2, 10: -7, 11: 0, 12: -1,
               13: -2, 14: -7, 15: 0, 16: -1, 17: 4, 18: -3, 19: 3, 20: 2, 21: 4, 22: -3, 23: 3, 24: 2}


@dataclass(frozen=True)
class Constellation:
    """Circular orbits: per satellite its RAAN and argument of latitude at `epoch_gps_s`."""
    system: str                         # "GPS" or "GLO"
    ids: np.ndarray                     # PRN (GPS) or slot (GLONASS)
    raan0_rad: np.ndarray               # inertial right ascension of the node at the epoch
    u0_rad: np.ndarray
    inclination_rad: float
    mean_motion_radps: float
    epoch_gps_s: float
    gha0_rad: float                     # Greenwich hour angle at the epoch

    @cached_property
    def semi_major_axis_m(self) -> float:
        return (MU_M3PS2 / self.mean_motion_radps ** 2) ** (1 / 3)

    @cached_property
    def node_rate_radps(self) -> float:
        """Nodal regression under J2 (about -0.04 deg a day for GPS)."""
        a = self.semi_major_axis_m
        return -1.5 * self.mean_motion_radps * J2 * (EARTH_RADIUS_M / a) ** 2 * math.cos(self.inclination_rad)

    def ecef_m(self, gps_s) -> np.ndarray:
        """Satellite positions, ECEF metres, at GPS time(s) `gps_s`: shape (n, 3), or
        (n, len(t), 3) for an array of times."""
        t = np.atleast_1d(np.asarray(gps_s, float) - self.epoch_gps_s)[None, :]
        u = self.u0_rad[:, None] + self.mean_motion_radps * t
        node = self.raan0_rad[:, None] - self.gha0_rad + (self.node_rate_radps - OMEGA_E_RADPS) * t
        a, ci, si = self.semi_major_axis_m, math.cos(self.inclination_rad), math.sin(self.inclination_rad)
        cu, su, cn, sn = np.cos(u), np.sin(u), np.cos(node), np.sin(node)
        xyz = a * np.stack([cu * cn - su * ci * sn, cu * sn + su * ci * cn, su * si], axis=-1)
        return xyz[:, 0, :] if np.ndim(gps_s) == 0 else xyz

    def sat_ecef_m(self, index: int, gps_s: float) -> tuple[float, float, float]:
        """One satellite's position (the index of its id in `ids`), on floats: light-time
        iterations call this a few times per satellite and epoch."""
        t = gps_s - self.epoch_gps_s
        u = float(self.u0_rad[index]) + self.mean_motion_radps * t
        node = float(self.raan0_rad[index]) - self.gha0_rad + (self.node_rate_radps - OMEGA_E_RADPS) * t
        a, ci, si = self.semi_major_axis_m, math.cos(self.inclination_rad), math.sin(self.inclination_rad)
        cu, su, cn, sn = math.cos(u), math.sin(u), math.cos(node), math.sin(node)
        return a * (cu * cn - su * ci * sn), a * (cu * sn + su * ci * cn), a * su * si


def _repeat_motion(revolutions_per_day: float, days: float, inclination_deg: float) -> float:
    """The mean motion whose ground track repeats after `days` sidereal days of
    `revolutions_per_day * days` revolutions, with the node's regression (two passes)."""
    n = revolutions_per_day * OMEGA_E_RADPS
    for _ in range(3):
        a = (MU_M3PS2 / n ** 2) ** (1 / 3)
        node_rate = -1.5 * n * J2 * (EARTH_RADIUS_M / a) ** 2 * math.cos(math.radians(inclination_deg))
        n = revolutions_per_day * (OMEGA_E_RADPS - node_rate)
    return n


def gps() -> Constellation:
    slots = sorted(GPS_SLOTS)
    return Constellation(
        "GPS", np.array([GPS_PRN_OF_SLOT[s] for s in slots]),
        np.radians([GPS_SLOTS[s][0] for s in slots]), np.radians([GPS_SLOTS[s][1] for s in slots]),
        math.radians(55.0), _repeat_motion(2.0, 1.0, 55.0), SLOT_EPOCH_GPS_S, math.radians(SLOT_EPOCH_GHA_DEG))


def glonass() -> Constellation:
    """Slots 1-8 in plane 1, 9-16 in plane 2, 17-24 in plane 3; 17 revolutions in 8 sidereal
    days. The phases at the (arbitrary) epoch are the nominal ones of the slot layout."""
    slots = np.arange(1, 25)
    plane = (slots - 1) // 8
    raan = np.radians(251.0 + 120.0 * plane)
    u = np.radians(-45.0 * ((slots - 1) % 8) + 15.0 * plane)
    return Constellation("GLO", slots, raan, u, math.radians(64.8), _repeat_motion(17 / 8, 8.0, 64.8),
                         SLOT_EPOCH_GPS_S, math.radians(SLOT_EPOCH_GHA_DEG))


GPS = gps()
GLONASS = glonass()
CONSTELLATIONS = {"GPS": GPS, "GLO": GLONASS}


def glonass_frequencies_hz(slot: int) -> tuple[float, float]:
    k = GLONASS_FCN[slot]
    return GLONASS_L1_HZ + k * GLONASS_L1_STEP_HZ, GLONASS_L2_HZ + k * GLONASS_L2_STEP_HZ


def look_angles(receiver_ecef_m, sats_ecef_m: np.ndarray, rot_ecef_to_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(elevation, azimuth) in radians of satellites seen from a receiver."""
    los = (sats_ecef_m - np.asarray(receiver_ecef_m)) @ rot_ecef_to_enu.T
    horizontal = np.hypot(los[..., 0], los[..., 1])
    return np.arctan2(los[..., 2], horizontal), np.arctan2(los[..., 0], los[..., 1]) % (2 * math.pi)
