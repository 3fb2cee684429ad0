"""A recorded drive with a pilot in it, made offline: the laptop tests' drive
(laptop_helpers.write_drive) copied with what viena-pilot publishes added, its route made
by the pilot's own code (parse_route, path_sample) from checkpoints along the simulated
truth, so the route lies on the track when both are drawn in one frame."""
from __future__ import annotations

import json
from pathlib import Path

import pymap3d
from laptop_helpers import TRUTH_KEY, write_drive

from viena.common.recording import Recording, RecordingWriter
from viena.common.samples.pilot import PATH, STATE, path_sample
from viena.services.pilot.model.route import parse_route

PATH_KEY = "viena/elettra/pilot/path"
STATE_KEY = "viena/elettra/pilot/state"
PATH_PERIOD_S = 5.0            # as viena-pilot republishes it (services/pilot/service.py)
STATE_PERIOD_S = 0.05


def checkpoints_of(truth: list[dict], every_s: float, offset_m: float = 0.0) -> list[tuple[float, float]]:
    """(lat, lon) of the truth every `every_s` seconds once moving, shifted east by offset_m."""
    points = []
    for s in truth[::int(every_s * 100)]:
        e, n, _ = s["enu_m"]
        lat, lon, _ = pymap3d.enu2geodetic(e + offset_m, n, 0.0, *s["origin"])
        if not points or abs(lat - points[-1][0]) + abs(lon - points[-1][1]) > 1e-7:
            points.append((float(lat), float(lon)))
    return points


def geojson_route(points: list[tuple[float, float]], speeds=None) -> bytes:
    """The route as a person sends it: a GeoJSON LineString, [lon, lat] per point."""
    props = {} if speeds is None else {"speeds_mps": speeds}
    return json.dumps({"type": "Feature", "properties": props, "geometry": {
        "type": "LineString", "coordinates": [[lon, lat] for lat, lon in points]}}).encode()


def pilot_state(t_ns: int, seq: int, mode: str, reason: str | None = None) -> dict:
    return {"t": t_ns, "seq": seq, "mode": mode, "reason": reason, "controller": "pure_pursuit",
            "armed": mode == "following", "route_points": 0, "route_length_m": None, "checkpoint": None,
            "checkpoint_distance_m": None, "checkpoint_bearing_deg": None,
            "checkpoint_heading_error_deg": None, "progress_m": None, "progress": None,
            "cross_track_m": None, "heading_error_deg": None, "wheel_cmd_deg": None, "lookahead_m": None,
            "target_enu_m": None, "route_speed_mps": None, "estimate_age_s": None, "setpoints": seq}


def write_pilot_drive(path: Path, seconds: float, routes: list[tuple[float, bytes]],
                      modes: list[tuple[float, str, str | None]] = ()) -> dict:
    """A drive of `seconds` with, from each (start_s, route payload) of `routes`, that route
    on pilot/path every PATH_PERIOD_S until the next, and pilot states at 20 Hz whose mode
    is that of the last (start_s, mode, reason) of `modes` begun. Returns what was written,
    by key, with `"routes"`: the parsed routes."""
    plain = path.with_name(path.stem + "-plain.mcap")
    written = write_drive(plain, seconds=seconds)
    t0 = written[TRUTH_KEY][0]["t"]
    parsed = [(start_s, parse_route(payload)) for start_s, payload in routes]
    extra: list[tuple[int, str, str, bytes]] = []
    for i, (start_s, route) in enumerate(parsed):
        end_s = parsed[i + 1][0] if i + 1 < len(parsed) else seconds
        t_s = start_s
        while t_s < end_s:
            sample = path_sample(route, t0 + int(t_s * 1e9))
            extra.append((sample["t"], PATH_KEY, PATH.encoding, PATH.encode(sample)))
            written.setdefault(PATH_KEY, []).append(sample)
            t_s += PATH_PERIOD_S
    if modes:
        for seq in range(int(seconds / STATE_PERIOD_S)):
            t_s = seq * STATE_PERIOD_S
            mode, reason = "idle", None
            for start_s, m, why in modes:
                if start_s <= t_s:
                    mode, reason = m, why
            sample = pilot_state(t0 + int(t_s * 1e9), seq, mode, reason)
            extra.append((sample["t"], STATE_KEY, STATE.encoding, STATE.encode(sample)))
            written.setdefault(STATE_KEY, []).append(sample)
    extra.sort(key=lambda e: e[0])
    writer = RecordingWriter(path)
    pending = iter(extra)
    nxt = next(pending, None)
    for msg in Recording(plain).messages():
        while nxt is not None and nxt[0] + 2_000_000 <= msg.log_time:
            writer.write(nxt[1], nxt[2], nxt[0] + 2_000_000, nxt[3])
            nxt = next(pending, None)
        writer.write(msg.key, msg.encoding, msg.log_time, msg.data, msg.publish_time)
    for t, key, encoding, data in ([nxt] if nxt else []) + list(pending):
        writer.write(key, encoding, t + 2_000_000, data)
    writer.close()
    plain.unlink()
    written["routes"] = [route for _, route in parsed]
    return written
