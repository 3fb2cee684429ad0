"""The simulated car's loop (services/sim/model/route.py) as a pilot route: what a drive on
the sim profile follows, from a test, a benchmark or `viena sim run`."""
from __future__ import annotations

import numpy as np
import pymap3d

from viena.services.pilot.model.route import Route, checked
from viena.services.sim.model.route import default_route
from viena.services.sim.model.truth import IST_ORIGIN


def loop_route(every: int = 1) -> Route:
    """The sim's default loop as lat/lon checkpoints, one per `every` metre-spaced points,
    closed by its first point again."""
    pts = default_route().points[::every]
    return route_through(np.vstack([pts, pts[:1]]))


def loop_route_from(x_m: float, y_m: float, ahead_m: float = 2.0, short_m: float = 0.0) -> Route:
    """The loop as a route starting `ahead_m` beyond the loop point nearest (x, y) and
    closing there: once round from where the car is; with `short_m`, ending that far
    before its start instead (the loop's points are a metre apart)."""
    pts = default_route().points
    k = int(np.argmin(np.hypot(pts[:, 0] - x_m, pts[:, 1] - y_m)))
    k = (k + int(round(ahead_m))) % len(pts)
    lap = np.roll(pts, -k, axis=0)
    short = int(round(short_m))
    return route_through(lap[:len(lap) - short] if short > 0 else np.vstack([lap, lap[:1]]))


def route_through(points_enu_m) -> Route:
    """A route through the sim's ENU points (at its origin), as lat/lon checkpoints.

    One pymap3d call on the arrays (what LocalFrame.geodetic_of_enu_exact does per point,
    the same numbers): a benchmark asks for a route at every attempt to start, and ~30 ms
    of per-point calls each time showed in the lockstep car's profile."""
    pts = np.asarray(points_enu_m, float).reshape(-1, 2)
    lat, lon, _ = pymap3d.enu2geodetic(pts[:, 0], pts[:, 1], np.full(len(pts), IST_ORIGIN[2]), *IST_ORIGIN)
    latlon = list(zip(lat.tolist(), lon.tolist()))
    return checked(latlon, [None] * len(latlon), "points")
