"""The pilot's route in Foxglove (issue 17): a `pilot/path` sample becomes a
`foxglove.GeoJSON` message for the Map panel ([lon, lat], as GeoJSON orders them) and, in
the estimator's `enu`, a SceneUpdate line for the 3D panel; in the converter, in an
exported MCAP file read back with the mcap library, and through the live bridge to a
WebSocket client."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
from foxglove_client import FoxgloveClient, as_advertised, decoder, protobuf_decoder, read_all
from laptop_helpers import TRUTH_KEY, viena, write_drive
from pilot_drive import PATH_KEY, checkpoints_of, geojson_route, write_pilot_drive

from viena.common.samples.estimator import STATE
from viena.common.samples.pilot import PATH, path_sample
from viena.foxglove_messages import MAX_CHECKPOINT_MARKS, Converter
from viena.services.pilot.model.path import Path as PilotPath
from viena.services.pilot.model.route import parse_route

T0 = 1_717_236_000_123_456_789
ROUTE_TOPIC = "viena/elettra/foxglove/pilot/route"
SCENE_TOPIC = "viena/elettra/foxglove/pilot/scene"
ESTIMATOR_KEY = "viena/elettra/estimator/state"
#: three checkpoints near Lisbon, the second with an advised speed (lat, lon[, speed])
CSV = b"lat,lon,speed_mps\n38.7369000,-9.1395000\n38.7371000,-9.1393000,4.5\n38.7373500,-9.1394000\n"


def read(derived):
    """A derived message through the protobuf descriptors its own schema carries."""
    schema = type(derived.message).get_schema()
    return protobuf_decoder(schema.name, schema.data)(derived.message.encode())


def path_of(payload: bytes, t_ns: int = T0) -> dict:
    """The pilot's own sample of a route, through its schema as a subscriber gets it."""
    return PATH.decode(PATH.encode(path_sample(parse_route(payload), t_ns)))


def estimator_state(directory) -> dict:
    """A valid estimator state (the laptop tests' offline drive), with its ENU origin."""
    return write_drive(directory / "drive.mcap", seconds=1.0)[ESTIMATOR_KEY][-1]


def check_route_geojson(doc: dict, lat: list[float], lon: list[float]) -> None:
    """The FeatureCollection: one LineString through every checkpoint in [lon, lat] order,
    then a named Point per checkpoint, each exactly where the pilot has it."""
    assert doc["type"] == "FeatureCollection"
    line, *points = doc["features"]
    assert line["geometry"]["type"] == "LineString"
    assert line["geometry"]["coordinates"] == [[o, a] for a, o in zip(lat, lon)]    # lon first
    assert line["properties"]["name"].startswith(f"route: {len(lat)} checkpoints")
    assert line["properties"]["style"]["color"].startswith("#")
    assert [p["geometry"]["type"] for p in points] == ["Point"] * len(lat)
    assert [p["geometry"]["coordinates"] for p in points] == [[o, a] for a, o in zip(lat, lon)]
    assert points[0]["properties"]["name"] == "checkpoint 0 (start)"
    assert points[-1]["properties"]["name"] == f"checkpoint {len(lat) - 1} (end)"


def test_a_path_sample_is_a_geojson_route_lon_lat_with_named_checkpoints():
    converter = Converter()
    route = converter.route("viena/elettra/pilot/path", PATH.encoding)
    path = path_of(CSV)
    [out] = converter.derived(route, path)                       # no estimator origin yet: the map only
    assert (out.topic, out.kind) == (ROUTE_TOPIC, "GeoJson")
    assert type(out.message).get_schema().name == "foxglove.GeoJSON"
    doc = json.loads(read(out).geojson)
    check_route_geojson(doc, [38.7369, 38.7371, 38.73735], [-9.1395, -9.1393, -9.1394])
    assert doc["features"][2]["properties"]["name"] == "checkpoint 1, 4.5 m/s"   # its advised speed
    assert doc["features"][0]["properties"]["name"] == f"route: 3 checkpoints, {path['length_m']:.0f} m"


def test_after_an_estimator_state_the_route_is_also_the_line_the_pilot_follows_in_enu(tmp_path):
    converter = Converter()
    state = estimator_state(tmp_path)
    converter.derived(converter.route(ESTIMATOR_KEY, STATE.encoding), STATE.decode(STATE.encode(state)))
    out = {d.kind: d for d in converter.derived(converter.route("viena/elettra/pilot/path", PATH.encoding),
                                                  path_of(CSV))}
    assert set(out) == {"GeoJson", "SceneUpdate"} and out["SceneUpdate"].topic == SCENE_TOPIC
    [entity] = read(out["SceneUpdate"]).entities
    assert entity.frame_id == "enu" and entity.id == "route"
    assert (entity.timestamp.seconds, entity.timestamp.nanos) == (T0 // 10**9, T0 % 10**9)
    [line] = entity.lines
    pilot = PilotPath.from_route(parse_route(CSV), tuple(state["origin"]))   # what the pilot steers along
    assert np.allclose([[p.x, p.y] for p in line.points], pilot.points, atol=1e-6)
    assert all(p.z == 0.0 for p in line.points)
    assert np.allclose([[s.pose.position.x, s.pose.position.y] for s in entity.spheres], pilot.points, atol=1e-6)


def test_a_long_recorded_route_marks_only_its_ends_and_a_broken_path_nothing():
    converter = Converter()
    route = converter.route("viena/elettra/pilot/path", PATH.encoding)
    n = MAX_CHECKPOINT_MARKS + 1
    lat = (38.7369 + 2e-5 * np.arange(n)).tolist()                 # a point every ~2 m, northwards
    lon = [-9.1395] * n
    csv = "\n".join(f"{a:.7f},{o:.7f}" for a, o in zip(lat, lon)).encode()
    [out] = converter.derived(route, path_of(csv))
    doc = json.loads(read(out).geojson)
    line, *points = doc["features"]
    assert len(line["geometry"]["coordinates"]) == n
    assert [p["properties"]["name"] for p in points] == ["checkpoint 0 (start)", f"checkpoint {n - 1} (end)"]
    broken = {**path_of(CSV), "lon_deg": [-9.1395]}                 # fewer longitudes than latitudes
    assert converter.derived(route, broken) == []


@pytest.mark.slow  # a drive recorded and exported through the CLI
def test_the_export_holds_the_route_on_its_geojson_and_scene_channels(tmp_path):
    plain = write_drive(tmp_path / "plain.mcap", seconds=12.0)
    points = checkpoints_of(plain[TRUTH_KEY], every_s=2.0)
    drive = tmp_path / "drive.mcap"
    written = write_pilot_drive(drive, 12.0, [(1.0, geojson_route(points))])
    out = tmp_path / "drive-fox.mcap"
    result = viena("export", drive, "--format", "foxglove", "-o", out)
    assert result.returncode == 0, result.stderr
    summary, messages = read_all(out)
    channels = {c.topic: (c, summary.schemas[c.schema_id]) for c in summary.channels.values() if c.schema_id}
    route_channel, route_schema = channels[ROUTE_TOPIC]
    assert (route_schema.name, route_schema.encoding, route_channel.message_encoding) == \
        ("foxglove.GeoJSON", "protobuf", "protobuf")
    decode = decoder(as_advertised(route_channel, route_schema))
    maps = [(m.log_time, json.loads(decode(m.data).geojson)) for _, c, m in messages if c.topic == ROUTE_TOPIC]
    samples = written[PATH_KEY]
    assert [t for t, _ in maps] == [s["t"] + 2_000_000 for s in samples]   # each at its sample's log time
    lat, lon = [p[0] for p in points], [p[1] for p in points]
    for _, doc in maps:
        check_route_geojson(doc, lat, lon)
    scene_channel, scene_schema = channels[SCENE_TOPIC]
    assert scene_schema.name == "foxglove.SceneUpdate"
    scenes = [decoder(as_advertised(scene_channel, scene_schema))(m.data)
              for _, c, m in messages if c.topic == SCENE_TOPIC]
    assert len(scenes) == len(samples)                     # the estimator's origin came first
    pilot = PilotPath.from_route(written["routes"][0], tuple(plain[TRUTH_KEY][0]["origin"]))
    for scene in scenes:
        assert np.allclose([[p.x, p.y] for p in scene.entities[0].lines[0].points], pilot.points, atol=1e-6)
    as_json = [json.loads(m.data) for _, c, m in messages if c.topic == PATH_KEY]
    check_path = decoder(as_advertised(*channels[PATH_KEY]))
    for _, c, m in messages:
        if c.topic == PATH_KEY:
            check_path(m.data)                     # passes its own schema (speeds may be null)
    assert [(j["lat_deg"], j["lon_deg"]) for j in as_json] == [(s["lat_deg"], s["lon_deg"]) for s in samples]


@pytest.fixture
def live_bridge(session):
    """`viena foxglove`'s bridge and server in this process, on the test router: (session, port)."""
    import foxglove

    from viena.foxglove import Bridge
    from viena.foxglove_channels import FoxgloveChannels

    context = foxglove.Context()
    server = foxglove.start_server(name="viena elettra", host="127.0.0.1", port=0, context=context,
                                   supported_encodings=["json"])
    channels = FoxgloveChannels(context)
    bridge = Bridge(session, "viena/elettra/**", channels)
    bridge.start()
    try:
        yield session, server.port
    finally:
        bridge.stop()
        server.stop()
        channels.close()


def test_the_live_bridge_sends_the_route_to_a_client_on_its_map_and_in_3d(live_bridge, tmp_path):
    session, port = live_bridge
    state = STATE.encode(estimator_state(tmp_path))
    path = path_sample(parse_route(CSV), T0)

    def put_both():                        # as the car does: estimator at its rate, the path every 5 s
        session.put(ESTIMATOR_KEY, state, encoding=STATE.encoding)
        session.put(PATH_KEY, PATH.encode(path), encoding=PATH.encoding)

    with FoxgloveClient(port) as client:
        put_both()                                               # the first samples advertise the channels
        assert client.wait_for_topics([ROUTE_TOPIC, SCENE_TOPIC, "viena/elettra/foxglove/tf"], timeout=20)
        wanted = [client.channel(t) for t in (ROUTE_TOPIC, SCENE_TOPIC, "viena/elettra/foxglove/tf")]
        client.subscribe(wanted)                                 # the tf, as Foxglove's 3D panel does
        got: dict[str, list] = {}
        end = time.monotonic() + 20
        while not {ROUTE_TOPIC, SCENE_TOPIC} <= set(got) and time.monotonic() < end:
            put_both()
            for message in client.messages(0.3):
                got.setdefault(message.channel["topic"], []).append(decoder(message.channel)(message.payload))
    assert {ROUTE_TOPIC, SCENE_TOPIC} <= set(got), sorted(got)
    assert client.channel(ROUTE_TOPIC)["schemaName"] == "foxglove.GeoJSON"
    check_route_geojson(json.loads(got[ROUTE_TOPIC][0].geojson), path["lat_deg"], path["lon_deg"])
    assert got[SCENE_TOPIC][0].entities[0].frame_id == "enu"
