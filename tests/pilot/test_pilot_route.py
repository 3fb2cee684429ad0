"""Routes in every accepted form, read alike; bad routes refused with one clear reason each."""
from __future__ import annotations

import json

import msgpack
import numpy as np
import pytest

from viena.services.pilot.model.path import Path
from viena.services.pilot.model.route import (
    MAX_ROUTE_BYTES,
    TITANS_FINAL,
    TITANS_LAT,
    TITANS_LON,
    RouteError,
    distance_to_route_m,
    parse_route,
)
from viena.services.pilot.model.sim_loop import loop_route
from viena.services.sim.model.truth import IST_ORIGIN

LAT, LON = 38.7369, -9.1395
# three checkpoints about 10 m apart, north then east
POINTS = [(LAT, LON), (LAT + 0.0001, LON), (LAT + 0.0001, LON + 0.00012)]


def as_geojson(points, speeds=None) -> bytes:
    feature = {"type": "Feature", "properties": {},
               "geometry": {"type": "LineString", "coordinates": [[lon, lat] for lat, lon in points]}}
    if speeds:
        feature["properties"]["speeds_mps"] = speeds
    return json.dumps(feature).encode()


def as_titans(points) -> list[dict]:
    """As the Titans' app sent them: one APP_START_STOP message per checkpoint, at the
    signal's resolution (1e-6 deg), the last one flagged final."""
    return [{TITANS_LAT: round(lat, 6), TITANS_LON: round(lon, 6), "APP_COORDINATE_READY": 1,
             TITANS_FINAL: int(i == len(points) - 1)} for i, (lat, lon) in enumerate(points)]


# -- every form ---------------------------------------------------------------------------------
def test_geojson_linestring_in_every_wrapping_reads_the_same():
    bare = {"type": "LineString", "coordinates": [[lon, lat] for lat, lon in POINTS]}
    feature = json.loads(as_geojson(POINTS))
    collection = {"type": "FeatureCollection", "features": [feature]}
    for obj in (bare, feature, collection):
        route = parse_route(json.dumps(obj))
        assert route.points == tuple(POINTS) and route.form == "geojson"
    with_height = {"type": "LineString", "coordinates": [[lon, lat, 100.0] for lat, lon in POINTS]}
    assert parse_route(json.dumps(with_height)).points == tuple(POINTS)


def test_geojson_point_list_and_multipoint():
    points = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"speed_mps": 3.0}, "geometry": {"type": "Point", "coordinates": [lon, lat]}}
        for lat, lon in POINTS]}
    route = parse_route(json.dumps(points))
    assert route.points == tuple(POINTS) and route.speeds_mps == (3.0, 3.0, 3.0)
    multi = {"type": "MultiPoint", "coordinates": [[lon, lat] for lat, lon in POINTS]}
    assert parse_route(json.dumps(multi)).points == tuple(POINTS)


def test_plain_point_list_as_json_and_msgpack():
    items = [{"lat": lat, "lon": lon, "speed_mps": 4} for lat, lon in POINTS]
    for payload in (json.dumps(items).encode(), msgpack.packb(items), json.dumps({"points": items}).encode()):
        route = parse_route(payload)
        assert route.points == tuple(POINTS) and route.speeds_mps == (4.0, 4.0, 4.0) and route.form == "points"


def test_csv_with_and_without_header_and_speeds():
    plain = "\n".join(f"{lat},{lon}" for lat, lon in POINTS)
    assert parse_route(plain).points == tuple(POINTS)
    fancy = "# recorded on campus\nlat,lon,speed_mps\n" + "\n".join(f"{lat}, {lon}, 2.5" for lat, lon in POINTS) + "\n"
    route = parse_route(fancy)
    assert route.points == tuple(POINTS) and route.speeds_mps == (2.5, 2.5, 2.5) and route.form == "csv"


def test_titans_checkpoints():
    for obj in (as_titans(POINTS), {"checkpoints": as_titans(POINTS)}):
        route = parse_route(json.dumps(obj))
        assert route.form == "titans" and len(route) == 3
        assert np.allclose(route.points, POINTS, atol=1e-6)


def test_titans_checkpoints_and_geojson_give_the_same_path():
    """The loop sent both ways: the paths agree to the Titans signal's resolution (1e-6 deg,
    about 0.1 m)."""
    route = loop_route()
    geo = parse_route(as_geojson(route.points))
    titans = parse_route(json.dumps(as_titans(route.points)))
    a, b = Path.from_route(geo, IST_ORIGIN), Path.from_route(titans, IST_ORIGIN)
    assert len(a.points) == len(b.points) == len(route)
    assert np.max(np.hypot(*(a.points - b.points).T)) < 0.1
    assert abs(a.length_m - b.length_m) < 0.2


def test_to_geojson_round_trips():
    route = parse_route(as_geojson(POINTS, [1.0, 2.0, 3.0]))
    again = parse_route(json.dumps(route.to_geojson()))
    assert again.points == route.points and again.speeds_mps == (1.0, 2.0, 3.0)
    assert route.to_geojson()["properties"]["points"] == 3


# -- bad routes: one clear reason each ----------------------------------------------------------
BAD = {
    "empty": (b"", "empty route"),
    "blank": (b"  \n", "empty route"),
    "no points": (json.dumps({"type": "LineString", "coordinates": []}), "no points"),
    "one point": (as_geojson(POINTS[:1]), "1 point: at least 2"),
    "NaN": (b'[{"lat": 38.7, "lon": -9.1}, {"lat": NaN, "lon": -9.1}]', "point 1: latitude is not finite"),
    "infinite in csv": ("38.7,-9.1\n38.7001,inf\n", "line 2: longitude is not finite"),
    "latitude beyond 90": (as_geojson([(LAT, LON), (91.0, LON)]), "point 1: latitude 91.0 is beyond +-90"),
    "text for a number": (json.dumps([{"lat": "38.7", "lon": -9.1}, {"lat": 38.7, "lon": -9.1}]),
                          "point 0: latitude must be a number"),
    "bool for a number": (json.dumps([{"lat": True, "lon": -9.1}, {"lat": 38.7, "lon": -9.1}]),
                          "point 0: latitude must be a number"),
    "a point not a map": (json.dumps([[38.7, -9.1], [38.71, -9.1]]), "point 0: expected a map"),
    "unknown field": (json.dumps([{"lat": 38.7, "lon": -9.1, "alt": 3}]), "point 0: unknown field 'alt'"),
    "coordinate pair too short": (json.dumps({"type": "LineString", "coordinates": [[1.0], [2.0, 3.0]]}),
                                  "point 0: expected [lon, lat]"),
    "polygon": (json.dumps({"type": "Polygon", "coordinates": []}), "a route is a LineString"),
    "duplicate consecutive": (as_geojson([POINTS[0], POINTS[1], POINTS[1], POINTS[2]]),
                              "points 1 and 2 are the same place"),
    "negative speed": (json.dumps([{"lat": LAT, "lon": LON, "speed_mps": -1}, {"lat": LAT + 1e-4, "lon": LON}]),
                       "point 0: speed must be"),
    "too long a leg": (as_geojson([(LAT, LON), (LAT + 0.1, LON)]), "11.1 km apart"),
    "csv garbage": ("38.7,-9.1\nhello,world\n", "line 2: 'hello,world' is not numbers"),
    "csv one field": ("38.7\n38.8\n", "expected lat,lon[,speed_mps], got 1 fields"),
    "bad json": (b'{"type": "LineString", ', "not valid JSON"),
    "bad msgpack": (b"\x92\xc1", "not valid msgpack"),
    "titans unfinished": (json.dumps(as_titans(POINTS)[:2] + [{TITANS_LAT: LAT, TITANS_LON: LON + 1e-3}]),
                          "no checkpoint has APP_FINAL_COORDINATE = 1"),
    "titans after final": (json.dumps(as_titans(POINTS) + as_titans(POINTS)[:1]),
                           "checkpoint 3 comes after checkpoint 2, flagged final"),
    "a number": (b"[1, 2]", "point 0: expected a map"),
    "wrong map": (json.dumps({"lat": 1}), "a map without 'type'"),
    "two lines": (json.dumps({"type": "FeatureCollection", "features": [json.loads(as_geojson(POINTS))] * 2}),
                  "2 LineStrings: send one"),
    "speeds do not match": (as_geojson(POINTS, [1.0]), "one speed per coordinate"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_route_is_refused_with_its_reason(name):
    payload, reason = BAD[name]
    with pytest.raises(RouteError) as err:
        parse_route(payload)
    assert reason in str(err.value)
    assert "\n" not in str(err.value)


def test_a_megabyte_of_points_is_refused_before_it_is_parsed():
    huge = json.dumps([{"lat": LAT + i * 1e-5, "lon": LON} for i in range(30000)]).encode()
    assert len(huge) > MAX_ROUTE_BYTES
    with pytest.raises(RouteError, match="bytes: at most"):
        parse_route(huge)


def test_too_many_points_even_when_small_enough():
    csv = "\n".join(f"{LAT + i * 2e-6:.6f},{LON}" for i in range(6000))
    assert len(csv) < MAX_ROUTE_BYTES
    with pytest.raises(RouteError, match="6000 points: at most 5000"):
        parse_route(csv)


def test_distance_to_route():
    route = parse_route(as_geojson(POINTS))
    assert distance_to_route_m(route, LAT, LON) == pytest.approx(0.0, abs=1e-6)
    assert distance_to_route_m(route, LAT + 0.09, LON) == pytest.approx(0.09 * 111_000 - 11, rel=0.01)
