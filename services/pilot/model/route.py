"""A route of checkpoints: what people and programs send, read and checked in one place.

Accepted forms (docs/pilot.md#routes), as JSON text, msgpack or CSV text:

- GeoJSON: a LineString (bare, in a Feature, or the one LineString of a FeatureCollection),
  a MultiPoint, or a FeatureCollection of Points in order; coordinates are [lon, lat(, h)]
  as GeoJSON says. Speeds, if any, in `properties.speeds_mps` (a LineString) or each
  Point's `properties.speed_mps`;
- a point list: `[{"lat": .., "lon": .., "speed_mps": ..}, ...]`, or `{"points": [...]}`;
- Titans-style checkpoints, the CAN signals its phone app sent one checkpoint at a time
  (seed: DBC message APP_START_STOP): `[{"APP_ROUTE_latitude": .., "APP_ROUTE_longitude":
  .., "APP_FINAL_COORDINATE": 0|1}, ...]` or `{"checkpoints": [...]}`; the last one is
  flagged final, and nothing may follow it;
- CSV: one `lat,lon[,speed_mps]` per line; a header line and `#` comments are skipped.

Every refusal is a `RouteError` with one reason naming the point at fault, the client's
own text in it cut short and printable. What arrives is bounded before it is read: at most
MAX_ROUTE_BYTES, nested at most MAX_DEPTH levels (a 200,000-deep `[[[...` is refused in
0.1 ms, never a RecursionError). Reading a 5,000-point route takes about 20 ms: the service
does it off its control thread (services/pilot/inbox.py). Nothing here knows where the car
is: `distance_to_route_m` lets the service check that.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pymap3d

from viena.common.errors import SampleError
from viena.common.payload import nesting_depth
from viena.common.schema import unpack
from viena.common.text import printable

#: a route is at most this big on the wire (a 5,000-point GeoJSON is ~200 kB)
MAX_ROUTE_BYTES = 256 * 1024
#: the deepest route form, a FeatureCollection's LineString, nests 6 levels of maps and lists
MAX_DEPTH = 8
MAX_POINTS = 5000
#: consecutive points closer than this are the same place
MIN_SPACING_M = 0.1
#: the longest leg between two consecutive checkpoints: beyond this a typo is likelier
MAX_LEG_M = 1000.0
TITANS_LAT, TITANS_LON, TITANS_FINAL = "APP_ROUTE_latitude", "APP_ROUTE_longitude", "APP_FINAL_COORDINATE"


class RouteError(ValueError):
    """A route that cannot be followed; the message is the one reason."""


@dataclass(frozen=True)
class Route:
    """Checkpoints in order: (lat_deg, lon_deg), and an advised speed for each or None."""

    points: tuple[tuple[float, float], ...]
    speeds_mps: tuple[float | None, ...]
    form: str                                   # which form it came in: geojson, points, titans, csv

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def legs_m(self) -> tuple[float, ...]:
        """Length of each leg, on the ellipsoid (worked out once: a route is never changed)."""
        return tuple(float(v) for v in _distances_m(self.points[:-1], self.points[1:]))

    @cached_property
    def length_m(self) -> float:
        return sum(self.legs_m)

    def to_geojson(self) -> dict:
        """The route as a GeoJSON Feature (what `pilot/route` answers, what `route show` prints)."""
        props: dict = {"form": self.form, "length_m": round(self.length_m, 3), "points": len(self)}
        if any(v is not None for v in self.speeds_mps):
            props["speeds_mps"] = list(self.speeds_mps)
        return {"type": "Feature", "properties": props,
                "geometry": {"type": "LineString", "coordinates": [[lon, lat] for lat, lon in self.points]}}


def _distances_m(a, b) -> np.ndarray:
    """Horizontal distances from each place of `a` to the same-numbered place of `b`
    ((lat_deg, lon_deg) pairs; either may be one place), in one vectorised call."""
    a, b = np.asarray(a, float).reshape(-1, 2), np.asarray(b, float).reshape(-1, 2)
    e, n, _ = pymap3d.geodetic2enu(b[:, 0], b[:, 1], 0.0, a[:, 0], a[:, 1], 0.0)
    return np.hypot(e, n)


# -- reading ----------------------------------------------------------------------------------
def parse_route(data: bytes | str, encoding: str | None = None) -> Route:
    """A checked Route from a payload in any accepted form; RouteError otherwise."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    data = bytes(data)
    if len(data) > MAX_ROUTE_BYTES:
        raise RouteError(f"route of {len(data)} bytes: at most {MAX_ROUTE_BYTES} are read")
    if not data.strip():
        raise RouteError("empty route: send GeoJSON, a point list, Titans checkpoints or CSV lat,lon")
    head = data.lstrip()[:1]
    if encoding and "msgpack" in encoding or (head and head[0] >= 0x80):
        try:
            obj = unpack(data, "route")             # msgpack's own stack stops at 1024 levels
        except SampleError as exc:
            raise RouteError(str(exc)) from None
        return route_from_object(_shallow(obj))
    if head in (b"{", b"["):
        try:
            obj = json.loads(data.decode("utf-8"), parse_constant=float)
        except RecursionError:                       # the C decoder's own guard, at ~1000 levels
            raise RouteError(f"nested deeper than {MAX_DEPTH} levels") from None
        except (UnicodeDecodeError, ValueError) as exc:
            raise RouteError(f"not valid JSON: {exc}") from None
        return route_from_object(_shallow(obj))
    try:
        return route_from_csv(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise RouteError("neither JSON, msgpack nor CSV text") from None


def _shallow(obj):
    """`obj`, if it nests at most MAX_DEPTH levels: deeper, even repr() of it could recurse
    past Python's limit, and no route form is that deep."""
    if nesting_depth(obj, MAX_DEPTH) > MAX_DEPTH:
        raise RouteError(f"nested deeper than {MAX_DEPTH} levels")
    return obj


def route_from_object(obj) -> Route:
    """A Route from parsed JSON or msgpack."""
    if isinstance(obj, dict):
        kind = obj.get("type")
        if kind is not None:
            return _geojson(obj)
        if "checkpoints" in obj:
            return _titans(obj["checkpoints"])
        if "points" in obj:
            return _point_list(obj["points"])
        raise RouteError("a map without 'type' (GeoJSON), 'points' or 'checkpoints'")
    if isinstance(obj, list):
        if obj and isinstance(obj[0], dict) and TITANS_LAT in obj[0]:
            return _titans(obj)
        return _point_list(obj)
    raise RouteError(f"expected GeoJSON, a list of points or checkpoints, got {type(obj).__name__}")


def route_from_csv(text: str) -> Route:
    points, speeds = [], []
    rows = [(i, line.strip()) for i, line in enumerate(text.splitlines(), 1)]
    rows = [(i, line) for i, line in rows if line and not line.startswith("#")]
    if rows and not _is_number(rows[0][1].split(",")[0]):
        rows = rows[1:]                                   # a header: lat,lon,speed
    if len(rows) > MAX_POINTS:                            # said before 60,000 lines are converted
        raise RouteError(f"the route has {len(rows)} points: at most {MAX_POINTS}")
    for i, line in rows:
        cells = [c.strip() for c in line.split(",")]
        if len(cells) not in (2, 3):
            raise RouteError(f"line {i}: expected lat,lon[,speed_mps], got {len(cells)} fields")
        try:
            values = [float(c) for c in cells]
        except ValueError:
            raise RouteError(f"line {i}: {_shown(line)} is not numbers lat,lon[,speed_mps]") from None
        points.append((values[0], values[1]))
        speeds.append(values[2] if len(values) == 3 else None)
    return checked(points, speeds, "csv", what="line")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _geojson(obj: dict) -> Route:
    kind = obj.get("type")
    if kind == "Feature":
        geometry = obj.get("geometry")
        if not isinstance(geometry, dict):
            raise RouteError("GeoJSON Feature without a geometry")
        props = obj.get("properties") or {}
        speeds = props.get("speeds_mps") if isinstance(props, dict) else None
        return _geometry(geometry, speeds)
    if kind == "FeatureCollection":
        features = obj.get("features")
        if not isinstance(features, list) or not features:
            raise RouteError("GeoJSON FeatureCollection without features")
        if not all(isinstance(f, dict) and isinstance(f.get("geometry"), dict) for f in features):
            raise RouteError("GeoJSON FeatureCollection: every feature needs a geometry")
        lines = [f for f in features if f["geometry"].get("type") == "LineString"]
        if len(lines) == 1:
            return _geojson(lines[0])
        if lines:
            raise RouteError(f"GeoJSON FeatureCollection with {len(lines)} LineStrings: send one")
        if all(f["geometry"].get("type") == "Point" for f in features):
            coords = [f["geometry"].get("coordinates") for f in features]
            speeds = [(f.get("properties") or {}).get("speed_mps") if isinstance(f.get("properties") or {}, dict)
                      else None for f in features]
            return _coordinates(coords, speeds)
        raise RouteError("GeoJSON FeatureCollection: expected one LineString or Points only")
    return _geometry(obj, None)


def _geometry(geometry: dict, speeds) -> Route:
    kind = geometry.get("type")
    if kind not in ("LineString", "MultiPoint"):
        raise RouteError(f"GeoJSON {_shown(kind)}: a route is a LineString or a MultiPoint")
    coords = geometry.get("coordinates")
    if not isinstance(coords, list):
        raise RouteError(f"GeoJSON {kind} without a list of coordinates")
    if speeds is not None and (not isinstance(speeds, list) or len(speeds) != len(coords)):
        raise RouteError("properties.speeds_mps must list one speed per coordinate")
    return _coordinates(coords, speeds)


def _coordinates(coords: list, speeds) -> Route:
    points = []
    for i, c in enumerate(coords):
        if not isinstance(c, (list, tuple)) or len(c) not in (2, 3):
            raise RouteError(f"point {i}: expected [lon, lat] or [lon, lat, height], got {_shown(c)}")
        points.append((c[1], c[0]))
    return checked(points, speeds or [None] * len(points), "geojson")


def _point_list(items) -> Route:
    if not isinstance(items, list):
        raise RouteError(f"points must be a list, got {type(items).__name__}")
    points, speeds = [], []
    for i, p in enumerate(items):
        if isinstance(p, dict):
            unknown = set(p) - {"lat", "lon", "speed_mps"}
            if unknown:
                raise RouteError(f"point {i}: unknown field {_shown(min(unknown, key=str))} "
                                 f"(expected lat, lon, speed_mps)")
            if "lat" not in p or "lon" not in p:
                raise RouteError(f"point {i}: needs lat and lon")
            points.append((p["lat"], p["lon"]))
            speeds.append(p.get("speed_mps"))
        else:
            raise RouteError(f"point {i}: expected a map like {{\"lat\": 38.7, \"lon\": -9.1}}, got {_shown(p)}")
    return checked(points, speeds, "points")


def _titans(items) -> Route:
    if not isinstance(items, list):
        raise RouteError("checkpoints must be a list")
    points = []
    final_at = None
    for i, msg in enumerate(items):
        if not isinstance(msg, dict) or TITANS_LAT not in msg or TITANS_LON not in msg:
            raise RouteError(f"checkpoint {i}: needs {TITANS_LAT} and {TITANS_LON}")
        if final_at is not None:
            raise RouteError(f"checkpoint {i} comes after checkpoint {final_at}, flagged final")
        points.append((msg[TITANS_LAT], msg[TITANS_LON]))
        if msg.get(TITANS_FINAL) in (1, True):
            final_at = i
    if points and final_at is None:
        raise RouteError(f"no checkpoint has {TITANS_FINAL} = 1: the route was not finished")
    return checked(points, [None] * len(points), "titans", what="checkpoint")


def _shown(v) -> str:
    """A client's value as it is shown back in a reason: short and printable."""
    return printable(repr(v))


# -- checking ---------------------------------------------------------------------------------
def checked(points: list, speeds: list, form: str, what: str = "point") -> Route:
    """The Route, if it can be followed: 2..MAX_POINTS points, finite and on the Earth,
    speeds finite and >= 0, consecutive points apart by MIN_SPACING_M..MAX_LEG_M."""
    if not points:
        raise RouteError("the route has no points: at least 2 are needed")
    if len(points) == 1:
        raise RouteError("the route has 1 point: at least 2 are needed")
    if len(points) > MAX_POINTS:
        raise RouteError(f"the route has {len(points)} points: at most {MAX_POINTS}")
    first = 1 if what == "line" else 0
    out: list[tuple[float, float]] = []
    out_speeds: list[float | None] = []
    for i, ((lat, lon), speed) in enumerate(zip(points, speeds)):
        name = f"{what} {i + first}"
        for label, v, limit in (("latitude", lat, 90.0), ("longitude", lon, 180.0)):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise RouteError(f"{name}: {label} must be a number, got {_shown(v)}")
            if not _finite(v):
                raise RouteError(f"{name}: {label} is not finite ({_shown(v)})")
            if not -limit <= v <= limit:
                raise RouteError(f"{name}: {label} {_shown(v)} is beyond +-{limit:g} deg")
        if speed is not None and (isinstance(speed, bool) or not isinstance(speed, (int, float))
                                  or not _finite(speed) or speed < 0):
            raise RouteError(f"{name}: speed must be a finite number >= 0 m/s, got {_shown(speed)}")
        out.append((float(lat), float(lon)))
        out_speeds.append(None if speed is None else float(speed))
    route = Route(tuple(out), tuple(out_speeds), form)
    for i, leg in enumerate(route.legs_m):
        if leg < MIN_SPACING_M:
            raise RouteError(f"{what}s {i + first} and {i + first + 1} are the same place "
                             f"({leg:.2f} m apart): drop one")
        if leg > MAX_LEG_M:
            raise RouteError(f"{what}s {i + first} and {i + first + 1} are {leg / 1000:.1f} km apart: "
                             f"at most {MAX_LEG_M:.0f} m between checkpoints")
    return route


def _finite(v: int | float) -> bool:
    """A finite number, as a float can hold it (JSON's 400-digit integers cannot)."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def distance_to_route_m(route: Route, lat_deg: float, lon_deg: float) -> float:
    """How far a place is from the route's nearest point (between checkpoints the
    legs are at most MAX_LEG_M, so this is what `max_route_distance_m` needs)."""
    return float(_distances_m([(lat_deg, lon_deg)], route.points).min())
