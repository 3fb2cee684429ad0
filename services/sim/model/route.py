"""The loop the simulated car drives: a closed polyline in local ENU metres."""
from __future__ import annotations

import bisect
import math

import numpy as np


class Route:
    """A closed path with a look-ahead query for pure pursuit."""

    #: where lookahead searches for the closest point: from 2 points before the last one found
    WINDOW = range(-2, 12)

    def __init__(self, points_enu: np.ndarray):
        self.points = np.asarray(points_enu, float)
        seg = np.diff(np.vstack([self.points, self.points[:1]]), axis=0)
        self._seglen = np.hypot(seg[:, 0], seg[:, 1])
        self._s = np.concatenate([[0.0], np.cumsum(self._seglen)])
        self.length_m = float(self._s[-1])
        self._last = 0
        # the same numbers as Python floats: pure pursuit reads a few of them every step,
        # and indexing numpy arrays one element at a time costs more than the arithmetic
        self._xs, self._ys = self.points[:, 0].tolist(), self.points[:, 1].tolist()
        self._s_list, self._seglen_list = self._s.tolist(), self._seglen.tolist()
        # lookahead's search window after each point: its indices and their coordinates
        n = len(self._xs)
        self._windows = [[(j, self._xs[j], self._ys[j]) for j in ((i + k) % n for k in self.WINDOW)]
                         for i in range(n)]

    def start_pose(self) -> tuple[float, float, float]:
        """First point and the yaw (ENU, CCW, 0 = North) along the first segment."""
        (x0, y0), (x1, y1) = self.points[0], self.points[1]
        return float(x0), float(y0), math.atan2(-(x1 - x0), y1 - y0)

    def point_at(self, s: float) -> tuple[float, float]:
        s = float(s) % self.length_m
        n = len(self._xs)
        i = min(bisect.bisect_right(self._s_list, s) - 1, n - 1)
        frac = (s - self._s_list[i]) / self._seglen_list[i]
        xs, ys, j = self._xs, self._ys, (i + 1) % n
        return xs[i] + frac * (xs[j] - xs[i]), ys[i] + frac * (ys[j] - ys[i])

    def lookahead(self, x: float, y: float, distance_m: float) -> tuple[float, float]:
        """The route point `distance_m` beyond the closest point near the last one found."""
        window = self._windows[self._last]
        d = [(px - x) ** 2 + (py - y) ** 2 for _, px, py in window]
        self._last = window[d.index(min(d))][0]       # the first of equals, as np.argmin
        return self.point_at(self._s_list[self._last] + distance_m)


def oval(straight_m: float = 40.0, radius_m: float = 12.0, step_m: float = 1.0) -> Route:
    """Two straights joined by half circles, counter-clockwise, starting heading North."""
    pts = []
    n_straight = int(straight_m / step_m)
    n_arc = int(math.pi * radius_m / step_m)
    for k in range(n_straight):                       # east side, northbound
        pts.append((radius_m, k * step_m))
    for k in range(n_arc):                            # north half circle, turning left
        a = math.pi * k / n_arc
        pts.append((radius_m * math.cos(a), straight_m + radius_m * math.sin(a)))
    for k in range(n_straight):                       # west side, southbound
        pts.append((-radius_m, straight_m - k * step_m))
    for k in range(n_arc):                            # south half circle
        a = math.pi + math.pi * k / n_arc
        pts.append((radius_m * math.cos(a), radius_m * math.sin(a)))
    return Route(np.array(pts))


def default_route() -> Route:
    """A 40 m x 24 m loop on the IST campus, about 155 m around."""
    return oval()
