"""The local ENU frame at an origin: ECEF in, ENU and geodetic out (pymap3d, WGS84).

The ECEF -> ENU rotation (docs/frames.md#ecef-to-enu) is the one used here;
the tests check pymap3d against it, and we use the library rather than the equation.
Shared by the simulated car's truth, the GNSS fixes and the estimator: pymap3d's exact
ECEF -> geodetic costs ~0.2 ms a call, too much for every sample on a Pi, so geodetic
coordinates come from an exact anchor plus its Jacobian (see geodetic_of_enu).
"""
from __future__ import annotations

import math

import numpy as np
import pymap3d

#: WGS84 (docs/frames.md#wgs84-and-geodesy)
WGS84_A_M = 6378137.0
WGS84_B_M = 6356752.314245


def normal_gravity(lat_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity (Somigliana) with the free-air height term, m/s^2."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)
    return g0 - 3.086e-6 * height_m


def plausible_ecef(x: float, y: float, z: float) -> bool:
    """Within 100 km of the WGS84 ellipsoid: anything else is not a car's position."""
    r = math.sqrt(x * x + y * y + z * z)
    return WGS84_B_M - 1e5 < r < WGS84_A_M + 1e5


class LocalFrame:
    """ENU at a geodetic origin (lat deg, lon deg, ellipsoidal height m)."""

    def __init__(self, lat_deg: float, lon_deg: float, height_m: float):
        self.origin = (float(lat_deg), float(lon_deg), float(height_m))
        # rows are the ENU axes in ECEF: the columns of pymap3d's rotation of unit vectors
        cols = [pymap3d.uvw2enu(*e, lat_deg, lon_deg) for e in np.eye(3)]
        self.rot_ecef_to_enu = np.array(cols, float).T
        self._rows = [float(v) for v in self.rot_ecef_to_enu.ravel()]
        self._origin_ecef = [float(v) for v in pymap3d.geodetic2ecef(lat_deg, lon_deg, height_m)]
        # pymap3d.enu2uvw's sines and cosines of the origin, from the numpy functions it calls
        lat, lon = np.radians(lat_deg), np.radians(lon_deg)
        self._trig = (float(np.cos(lat)), float(np.sin(lat)), float(np.cos(lon)), float(np.sin(lon)))
        self._cov_cache: dict = {}
        self.gravity_mps2 = normal_gravity(lat_deg, height_m)
        self._anchors: dict[tuple[int, int, int], tuple] = {}

    @classmethod
    def at_ecef(cls, ecef_m) -> LocalFrame:
        lat, lon, h = pymap3d.ecef2geodetic(*(float(v) for v in ecef_m))
        return cls(float(lat), float(lon), float(h))

    def enu_of_ecef(self, ecef_m) -> tuple[float, float, float]:
        """ENU is the rotation of the difference to the origin (docs/frames.md#ecef-to-enu), so a matrix
        product does what pymap3d.ecef2enu does, in a twentieth of the time."""
        x0, y0, z0 = self._origin_ecef
        dx, dy, dz = ecef_m[0] - x0, ecef_m[1] - y0, ecef_m[2] - z0
        r = self._rows
        return (r[0] * dx + r[1] * dy + r[2] * dz,
                r[3] * dx + r[4] * dy + r[5] * dz,
                r[6] * dx + r[7] * dy + r[8] * dz)

    def vector_of_enu(self, e: float, n: float, u: float) -> tuple[float, float, float]:
        """A free vector (velocity) from ENU axes to ECEF axes: pymap3d.enu2uvw's arithmetic, in the
        same order on the same constants (so the same bits), on floats: a tenth of its cost."""
        cos_lat, sin_lat, cos_lon, sin_lon = self._trig
        t = cos_lat * u - sin_lat * n
        return cos_lon * t - sin_lon * e, sin_lon * t + cos_lon * e, sin_lat * u + cos_lat * n

    def ecef_of_enu(self, e: float, n: float, u: float) -> tuple[float, float, float]:
        """ECEF of an ENU point, as pymap3d.enu2ecef (the same bits, see vector_of_enu)."""
        x0, y0, z0 = self._origin_ecef
        x, y, z = self.vector_of_enu(e, n, u)
        return x0 + x, y0 + y, z0 + z

    def geodetic_of_enu_exact(self, e: float, n: float, u: float) -> tuple[float, float, float]:
        lat, lon, h = pymap3d.enu2geodetic(e, n, u, *self.origin)
        return float(lat), float(lon), float(h)

    def geodetic_of_enu(self, e: float, n: float, u: float) -> tuple[float, float, float]:
        """Geodetic of an ENU point, to well under a millimetre, at a fraction of the cost.

        pymap3d's exact answer costs ~0.2 ms (it iterates), too much for every published
        state on a Pi. Near an anchor point solved exactly, geodetic coordinates are linear
        in ENU to second order: within 8.7 m of it (the anchors sit on a 10 m grid) the error
        is d^2 / R < 0.02 mm. The anchor is the grid point nearest the point, so the answer
        depends on the point alone, not on which points came before: two runs of a
        simulation give the same bytes whatever ran earlier in the process.
        """
        e, n, u = float(e), float(n), float(u)          # plain floats out, even from numpy
        cell = (round(e / self.ANCHOR_GRID_M), round(n / self.ANCHOR_GRID_M), round(u / self.ANCHOR_GRID_M))
        a = self._anchors.get(cell)
        if a is None:
            if len(self._anchors) > 64:
                self._anchors.clear()
            a = self._anchors[cell] = self._make_anchor(*(c * self.ANCHOR_GRID_M for c in cell))
        de, dn, du = e - a[0], n - a[1], u - a[2]
        j = a[6]
        return (a[3] + j[0] * de + j[1] * dn + j[2] * du,
                a[4] + j[3] * de + j[4] * dn + j[5] * du,
                a[5] + j[6] * de + j[7] * dn + j[8] * du)

    ANCHOR_GRID_M = 10.0

    def _make_anchor(self, e: float, n: float, u: float):
        base = self.geodetic_of_enu_exact(e, n, u)
        cols = []
        for de, dn, du in ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)):
            g = self.geodetic_of_enu_exact(e + de, n + dn, u + du)
            cols.append([g[k] - base[k] for k in range(3)])
        jac = [cols[c][r] for r in range(3) for c in range(3)]    # row-major d(geo)/d(enu)
        return (e, n, u, *base, jac)

    def geodetic_of_ecef(self, ecef_m) -> tuple[float, float, float]:
        return self.geodetic_of_enu(*self.enu_of_ecef(ecef_m))

    def vector_to_enu(self, vec_ecef) -> tuple[float, float, float]:
        """A free vector (velocity) from ECEF axes to ENU axes (plain floats)."""
        x, y, z = vec_ecef
        r = self._rows
        return (r[0] * x + r[1] * y + r[2] * z,
                r[3] * x + r[4] * y + r[5] * z,
                r[6] * x + r[7] * y + r[8] * z)

    def cov_to_enu(self, sigma_ecef) -> np.ndarray:
        """Covariance of ECEF per-axis sigmas seen in ENU axes: C diag(s^2) C^T.
        (Read-only: answers are kept, sigmas repeat from fix to fix.)"""
        key = tuple(sigma_ecef)
        cov = self._cov_cache.get(key)
        if cov is None:
            c = self.rot_ecef_to_enu
            cov = (c * np.square(np.asarray(key, float))) @ c.T
            cov.flags.writeable = False
            if len(self._cov_cache) > 16:
                self._cov_cache.clear()
            self._cov_cache[key] = cov
        return cov


#: local frames for geodetic_of_ecef, by the 10 km ECEF cell their origin is the centre of
FRAME_GRID_M = 10_000.0
_frames: dict[tuple[int, int, int], LocalFrame] = {}


def geodetic_of_ecef(x: float, y: float, z: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, ellipsoidal height m) of an ECEF point, to a millimetre.

    Fast for points that follow each other (a receiver's fixes): they share the local
    frame of their 10 km cell (and its anchors, LocalFrame.geodetic_of_enu), chosen by the
    point alone. Points far from the Earth's surface (a receiver's no-fix X=100, Y=Z=0) go
    to pymap3d directly."""
    if not plausible_ecef(x, y, z):
        lat, lon, h = pymap3d.ecef2geodetic(x, y, z)
        return float(lat), float(lon), float(h)
    cell = (round(x / FRAME_GRID_M), round(y / FRAME_GRID_M), round(z / FRAME_GRID_M))
    frame = _frames.get(cell)
    if frame is None:
        if len(_frames) > 64:
            _frames.clear()
        frame = _frames[cell] = LocalFrame.at_ecef(tuple(c * FRAME_GRID_M for c in cell))
    return frame.geodetic_of_ecef((x, y, z))
