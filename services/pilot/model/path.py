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
        first, last = 0, len(self.seg_len_m) - 1
        if near_s_m is not None:
            first = min(last, max(0, int(np.searchsorted(self.s_at, near_s_m - behind_m, side="right")) - 1))
            last = min(last, max(first, int(np.searchsorted(self.s_at, near_s_m + ahead_m, side="left"))))
        a = self.points[first:last + 1]
        t = self.tangents[first:last + 1]
        dx, dy = x_m - a[:, 0], y_m - a[:, 1]
        along = dx * t[:, 0] + dy * t[:, 1]
        lo = np.zeros_like(along)
        hi = self.seg_len_m[first:last + 1].copy()
        if first == 0:
            lo[0] = -np.inf                         # before the start: along the first leg
        if last == len(self.seg_len_m) - 1:
            hi[-1] = np.inf                         # beyond the end: along the last leg
        along = np.clip(along, lo, hi)
        px, py = a[:, 0] + along * t[:, 0], a[:, 1] + along * t[:, 1]
        dist = np.hypot(x_m - px, y_m - py)
        candidates = np.flatnonzero(dist <= dist.min() + TIE_M)
        k = int(candidates[np.argmin(dist[candidates])]) if near_s_m is not None else int(candidates[0])
        i = first + k
        tx, ty = float(t[k, 0]), float(t[k, 1])
        cross = tx * float(dy[k]) - ty * float(dx[k])
        return Projection(s_m=float(self.s_at[i] + along[k]), cross_track_m=cross,
                          path_yaw_rad=math.atan2(-tx, ty), segment=i,
                          x_m=float(px[k]), y_m=float(py[k]))

    def point_at(self, s_m: float) -> tuple[float, float]:
        """The path's point at progress s (continued straight beyond either end)."""
        i = int(np.searchsorted(self.s_at, s_m, side="right")) - 1
        i = min(max(i, 0), len(self.seg_len_m) - 1)
        along = s_m - self.s_at[i]
        a, t = self.points[i], self.tangents[i]
        return float(a[0] + along * t[0]), float(a[1] + along * t[1])

    def next_checkpoint(self, s_m: float) -> int | None:
        """Index of the first checkpoint still ahead of progress s, None past the last."""
        i = int(np.searchsorted(self.s_at, s_m, side="right"))
        return i if i < len(self.s_at) else None
