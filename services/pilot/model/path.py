"""The route as a polyline in the estimator's local ENU metres, and where the car is on it.

The estimator publishes its position in ENU at its `origin`; the path is built for that
origin (and rebuilt if the origin changes), so the pilot compares like with like and
needs no geodesy at the control rate. Frames as in docs/frames.md: x East, y North; yaw
counter-clockwise from North, so a heading's forward vector is (-sin yaw, cos yaw).

Progress `s` is the distance along the path from the first checkpoint. Before the first
point and beyond the last, the path continues along its first and last legs, so a car
overshooting the end has s > length_m (the route has ended) and a lookahead near the end
still has a point to aim at.
"""
from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np
import pymap3d

from viena.services.pilot.model.route import Route

#: when several parts of the path are about as near (a closed loop's start and end), the
#: one earliest along it wins, within this many metres
TIE_M = 0.5


def checkpoints_enu(lat_deg, lon_deg, origin: tuple[float, float, float]) -> np.ndarray:
    """Checkpoints as (east, north) rows in metres in the ENU frame at origin (lat_deg,
    lon_deg, height_m), taken at the origin's height: they are places on the road, with
    no height of their own. Every picture of a route (plot, Foxglove) uses this, so it
    shows the route where the pilot follows it."""
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    e, n, _ = pymap3d.geodetic2enu(lat, lon, np.full_like(lat, origin[2]), *origin)
    return np.column_stack([e, n])


@dataclass(frozen=True)
class Projection:
    """The car's nearest place on the path."""
    s_m: float                     # progress along the path (may be < 0 or > length)
    cross_track_m: float           # signed distance to the path, > 0: the car is left of it
    path_yaw_rad: float            # the path's direction there, as a yaw
    segment: int                   # index of the leg (between checkpoints segment, segment + 1)
    x_m: float                     # the nearest point on the path
    y_m: float


class Path:
    """A polyline in ENU metres with projection and look-ahead queries."""

    def __init__(self, points_enu_m, speeds_mps=None):
        pts = np.asarray(points_enu_m, float).reshape(-1, 2)
        if len(pts) < 2:
            raise ValueError("a path needs at least two points")
        self.points = pts
        seg = np.diff(pts, axis=0)
        self.seg_len_m = np.hypot(seg[:, 0], seg[:, 1])
        if np.any(self.seg_len_m <= 0):
            raise ValueError("a path cannot have two consecutive points at one place")
        self.tangents = seg / self.seg_len_m[:, None]
        self.s_at = np.concatenate([[0.0], np.cumsum(self.seg_len_m)])    # s of each checkpoint
        self.length_m = float(self.s_at[-1])
        self.speeds_mps = list(speeds_mps) if speeds_mps is not None else [None] * len(pts)
        # for `project`, which runs at the control rate: each leg's start, direction and the
        # bounds of the progress along it (open before the first leg and beyond the last),
        # as contiguous columns; and the checkpoints' s as floats for bisect
        self._ax, self._ay = pts[:-1, 0].copy(), pts[:-1, 1].copy()
        self._tx, self._ty = self.tangents[:, 0].copy(), self.tangents[:, 1].copy()
        self._lo = np.zeros(len(self.seg_len_m))
        self._lo[0] = -np.inf
        self._hi = self.seg_len_m.copy()
        self._hi[-1] = np.inf
        self._s_list = self.s_at.tolist()
        self._leg_list, self._tangent_list = pts.tolist(), self.tangents.tolist()   # for point_at

    @classmethod
    def from_route(cls, route: Route, origin: tuple[float, float, float]) -> Path:
        """The route in the ENU frame at origin (lat_deg, lon_deg, height_m); checkpoints
        taken at the origin's height (they are places on the road)."""
        lat_deg, lon_deg = zip(*route.points)
        return cls(checkpoints_enu(lat_deg, lon_deg, origin), route.speeds_mps)

    # -- queries --------------------------------------------------------------------------------
    def project(self, x_m: float, y_m: float, near_s_m: float | None = None,
                behind_m: float = 5.0, ahead_m: float = 20.0) -> Projection:
        """The nearest place on the path; with `near_s_m`, only among the legs within
        [near_s_m - behind_m, near_s_m + ahead_m], so a loop's end is not taken for its
        start and the car's progress moves on smoothly."""
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise ValueError(f"a position to project must be finite, got ({x_m}, {y_m})")
        first, last = 0, len(self.seg_len_m) - 1
        if near_s_m is not None:        # bisect on the floats: np.searchsorted's answers, a tenth of the cost
            first = min(last, max(0, bisect_right(self._s_list, near_s_m - behind_m) - 1))
            last = min(last, max(first, bisect_left(self._s_list, near_s_m + ahead_m)))
        end = last + 1
        ax, ay, tx, ty = self._ax[first:end], self._ay[first:end], self._tx[first:end], self._ty[first:end]
        dx, dy = x_m - ax, y_m - ay
        along = dx * tx + dy * ty
        along = np.minimum(np.maximum(along, self._lo[first:end]), self._hi[first:end])
        px, py = ax + along * tx, ay + along * ty
        dist = np.hypot(x_m - px, y_m - py)
        if near_s_m is not None:
            k = int(dist.argmin())      # the nearest; of equals, the earliest
        else:
            k = int(np.flatnonzero(dist <= dist.min() + TIE_M)[0])
        i = first + k
        tx_k, ty_k = float(tx[k]), float(ty[k])
        cross = tx_k * float(dy[k]) - ty_k * float(dx[k])
        return Projection(s_m=float(self.s_at[i] + along[k]), cross_track_m=cross,
                          path_yaw_rad=math.atan2(-tx_k, ty_k), segment=i,
                          x_m=float(px[k]), y_m=float(py[k]))

    def point_at(self, s_m: float) -> tuple[float, float]:
        """The path's point at progress s (continued straight beyond either end)."""
        i = bisect_right(self._s_list, s_m) - 1
        i = min(max(i, 0), len(self.seg_len_m) - 1)
        along = s_m - self._s_list[i]
        a, t = self._leg_list[i], self._tangent_list[i]
        return a[0] + along * t[0], a[1] + along * t[1]

    def next_checkpoint(self, s_m: float) -> int | None:
        """Index of the first checkpoint still ahead of progress s, None past the last."""
        i = bisect_right(self._s_list, s_m)
        return i if i < len(self._s_list) else None
