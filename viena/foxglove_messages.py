"""viena samples as Foxglove messages: what the live bridge (viena/foxglove.py) and the
export (`viena export --format foxglove`) both send. No I/O, no zenoh, no server here.

Every key is a JSON channel (`Converter.json`), with the JSON Schema generated from the
viena schema its encoding names (common/json_schema.py). Besides, some samples also say
something Foxglove's panels understand (`Converter.derived`), under `viena/<car>/foxglove/`:

| from | topic | Foxglove schema |
|---|---|---|
| `gnss/<unit>/fix` (valid fixes) | `foxglove/gnss/<unit>/location` | `foxglove.LocationFix` (the antenna) |
| `gnss/<unit>/fix` (every fix) | `foxglove/gnss/<unit>/status` | JSON `viena.foxglove.gnss_status/1` |
| `ntrip/state` | `foxglove/ntrip/status` | JSON `viena.foxglove.ntrip_status/1` |
| `estimator/state` | `foxglove/estimator/location` | `foxglove.LocationFix`, full ENU covariance |
| `estimator/state` | `foxglove/estimator/pose` | `foxglove.PoseInFrame` in frame `enu` |
| `sim/truth` | `foxglove/sim/truth/location`, `.../pose` | as above |
| `estimator/state`, `sim/truth` | `foxglove/tf` | `foxglove.FrameTransform` `enu` -> `car`, `enu` -> `car_truth` |
| `<service>/health` | `foxglove/log` | `foxglove.Log`, when an error counter grows |
| `pilot/path` | `foxglove/pilot/route` | `foxglove.GeoJSON`: the route's line and its checkpoints |
| `pilot/path` | `foxglove/pilot/scene` | `foxglove.SceneUpdate`: the route as a line in frame `enu` |

The status messages say on one channel what a person asks of a receiver (its solution
type and kind, the age of its corrections, the base station) and of the corrections link
(streaming or why not, bytes a second, how fresh).

Frames: `enu` is viena's local ENU world (x East, y North, z Up) at the estimator's or the
simulator's origin (the same configured origin on the car); `car` and `car_truth` are the
body frame (x right, y forward, z up), so Foxglove's 3D panel shows the car's axes as
viena defines them. LocationFix covariances are ENU, row-major, m^2; headings are
radians clockwise from north (viena's yaw is counter-clockwise: heading = -yaw).

The route's line in `enu` needs the estimator's origin (the pilot works in the estimator's
ENU): it is taken from the estimator states converted before, so the route's first
SceneUpdate comes with the first `pilot/path` after one (the pilot sends it every 5 s).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import orjson
from foxglove.messages import (
    Color,
    FrameTransform,
    GeoJson,
    LinePrimitive,
    LinePrimitiveLineType,
    LocationFix,
    LocationFixPositionCovarianceType,
    Log,
    LogLevel,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from viena.common.display import CORRECTIONS_STALE_S, number
from viena.common.geodesy import LocalFrame
from viena.common.json_schema import JsonForm
from viena.common.payload import to_jsonable
from viena.common.recording import decode_value
from viena.common.samples import topics  # the table: every contract's schema, registered by name
from viena.common.samples.fix import NO_FIX_ECEF, SOLUTION_KINDS, solution_kind, solution_rank
from viena.common.schema import F, Schema, schema_of
from viena.services.pilot.model.path import checkpoints_enu

WORLD_FRAME = "enu"
CAR_FRAME = "car"
TRUTH_FRAME = "car_truth"
#: LocationFix colours on the map: the estimator red, the truth black, receivers in turn
ESTIMATOR_COLOUR = Color(r=0.84, g=0.15, b=0.16, a=1.0)
TRUTH_COLOUR = Color(r=0.0, g=0.0, b=0.0, a=1.0)
GNSS_COLOURS = [Color(r=0.12, g=0.47, b=0.71, a=1.0), Color(r=0.17, g=0.63, b=0.17, a=1.0),
                Color(r=0.58, g=0.40, b=0.74, a=1.0), Color(r=1.0, g=0.50, b=0.05, a=1.0)]
#: the route: on the map (a Leaflet style, as Foxglove's Map panel takes it) and in 3D
ROUTE_COLOUR = Color(r=0.9, g=0.0, b=0.49, a=1.0)
ROUTE_STYLE = {"color": "#e6007e", "weight": 4, "opacity": 0.9}
CHECKPOINT_STYLE = {"color": "#e6007e"}
ROUTE_ENTITY = "route"
#: a route of more checkpoints than this (one recorded while driving, a point every few
#: metres) marks only its first and last: hundreds of pins would hide the map
MAX_CHECKPOINT_MARKS = 100
CHECKPOINT_SIZE_M = 0.6
#: a receiver's local frame (for its velocity and covariance in ENU) is made anew this far away
FRAME_REUSE_M = 1000.0


#: The status channels' messages: JSON, described by viena schemas like every key's
#: channel, so Foxglove plots any field (`.kind_level`, `.diff_age_s`) and a State
#: Transitions panel shows `.pos_type` or `.state`; `text` says it all on one line.
GNSS_STATUS = Schema("viena.foxglove.gnss_status/1", {
    "t": F.time,                        # the fix's epoch
    "unit": F.str,
    "valid": F.bool,
    "pos_status": F.str,
    "pos_type": F.str,                  # NovAtel's name: SINGLE, PSRDIFF, NARROW_FLOAT, NARROW_INT ...
    "kind": F.enum(*SOLUTION_KINDS),    # its class (common/samples/fix.py)
    "kind_level": F.int,                # the kind's place in SOLUTION_KINDS: 0 none ... 5 fixed
    "diff_age_s": F.optional(F.float),  # age of the corrections in the solution, when it uses any
    "sol_age_s": F.optional(F.float),
    "base_id": F.optional(F.str),
    "sats_used": F.optional(F.int),
    "sats_tracked": F.optional(F.int),
    "sigma_h_m": F.optional(F.float),   # the larger of the east and north sigmas (valid fixes)
    "sigma_v_m": F.optional(F.float),   # the up sigma
    "text": F.str,                      # e.g. "NARROW_INT (fixed), diff age 1.0 s, base 0042, 12/14 sats"
})
NTRIP_STATUS = Schema("viena.foxglove.ntrip_status/1", {
    "t": F.time,
    "caster": F.str,
    "mountpoint": F.str,
    "state": F.str,                     # connecting, streaming, waiting, refused, stopped
    "connected": F.bool,
    "stale": F.bool,                    # not streaming, or its last message older than CORRECTIONS_STALE_S
    "why": F.optional(F.str),
    "bytes_per_s": F.optional(F.float),
    "last_message_age_s": F.optional(F.float),
    "next_attempt_s": F.optional(F.float),
    "base_id": F.optional(F.str),
    "types": F.list(F.int),             # RTCM message numbers seen since the client started
    "frames": F.int,                    # of them, in all
    "text": F.str,
})
#: derived kinds that are JSON messages (the others are foxglove.channels classes)
JSON_KINDS = {"GnssStatus": JsonForm(GNSS_STATUS), "NtripStatus": JsonForm(NTRIP_STATUS)}

#: kinds whose conversion keeps what other channels need: the estimator's origin (the
#: route's 3D line is drawn in its ENU frame) and each service's error counts (its Log
#: says what grew): converted whether or not anyone watches them
STATEFUL_KINDS = frozenset({"estimator", "health"})


@dataclass(frozen=True)
class Route:
    """Where a key's samples go: its JSON channel's schema (None: schemaless JSON), the
    kind of Foxglove messages they make ('' for none) and those messages' (topic, kind)."""

    key: str
    encoding: str
    schema: Schema | None
    kind: str
    topics: list[tuple[str, str]]
    form: JsonForm | None = None

    def json_schema(self) -> dict | None:
        return None if self.form is None else self.form.schema

    def json(self, value: Any) -> bytes:
        """A decoded sample as the JSON text its channel's schema describes."""
        return json_bytes(value if self.form is None else self.form.value(value))


@dataclass(frozen=True)
class Derived:
    """A Foxglove message derived from a sample: its topic, its kind (`LocationFix`,
    `PoseInFrame`, `FrameTransform`, `Log`, `GeoJson`, `SceneUpdate`: the name of its
    foxglove.channels class without `Channel`; or a JSON_KINDS name, whose message is a
    map its JsonForm describes), and the message."""

    topic: str
    kind: str
    message: Any


def timestamp(t_ns: int) -> Timestamp:
    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


_strict_json = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def _hex(value: Any) -> str:
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    raise TypeError(type(value).__name__)


def json_bytes(value: Any) -> bytes:
    """A decoded sample as JSON text: non-finite floats as null, bytes as hex (JSON has
    neither). orjson writes it in one pass, NaN as null of its own; it is a fifth of the
    bridge's work with the standard library's encoder (docs/deployment.md#9-the-pis-budget).
    What orjson refuses (an integer beyond 64 bits, nesting beyond 254 levels, bytes or
    tuple keys) goes the standard library's way."""
    try:
        return orjson.dumps(value, default=_hex, option=orjson.OPT_NON_STR_KEYS)
    except TypeError:
        return _strict_json(to_jsonable(value)).encode()


class Converter:
    """viena samples -> Foxglove messages, for any car (its topics under its own
    `viena/<car>/foxglove/`). Keeps what a conversion needs from earlier samples: each
    service's error counts (to log what grew), each receiver's local frame, the
    estimator's origin (for the route in `enu`)."""

    def __init__(self):
        self._forms: dict[str, JsonForm | None] = {}
        self._errors: dict[str, dict[str, int]] = {}
        self._frames: dict[str, LocalFrame] = {}
        self._colours: dict[str, Color] = {}
        self._origin: tuple[float, float, float] | None = None

    def route(self, key: str, encoding: str) -> Route:
        """How samples of this key and encoding are converted (worked out once per key)."""
        schema = schema_of(encoding)
        kind = _derived_kind(schema)
        parts = key.split("/")
        form = None if schema is None else self._form(schema)
        if len(parts) < 3 or parts[0] != "viena":
            return Route(key, encoding, schema, "", [], form)
        root, local = f"viena/{parts[1]}/foxglove", parts[2:]
        tf = (f"{root}/tf", "FrameTransform")
        topics: list[tuple[str, str]] = []
        if kind == "fix" and len(local) == 3:
            topics = [(f"{root}/gnss/{local[1]}/location", "LocationFix"),
                      (f"{root}/gnss/{local[1]}/status", "GnssStatus")]
        elif kind == "ntrip":
            topics = [(f"{root}/ntrip/status", "NtripStatus")]
        elif kind == "estimator":
            topics = [(f"{root}/estimator/location", "LocationFix"), (f"{root}/estimator/pose", "PoseInFrame"), tf]
        elif kind == "truth":
            topics = [(f"{root}/sim/truth/location", "LocationFix"), (f"{root}/sim/truth/pose", "PoseInFrame"), tf]
        elif kind == "health":
            topics = [(f"{root}/log", "Log")]
        elif kind == "path":
            topics = [(f"{root}/pilot/route", "GeoJson"), (f"{root}/pilot/scene", "SceneUpdate")]
        return Route(key, encoding, schema, kind if topics else "", topics, form)

    def _form(self, schema: Schema) -> JsonForm | None:
        """The schema's JSON form; None (schemaless JSON) for a schema with a field no plain
        JSON type describes (raw bytes): its samples are still checked and sent."""
        if schema.name not in self._forms:
            try:
                self._forms[schema.name] = JsonForm(schema)
            except ValueError:
                self._forms[schema.name] = None
        return self._forms[schema.name]

    @staticmethod
    def decode(route: Route, data: bytes) -> Any:
        """A payload as checked values; a SampleError if it does not pass its schema (or is
        neither msgpack nor JSON)."""
        schema = route.schema
        return decode_value(data, route.encoding) if schema is None else schema.decode(data)

    def derived(self, route: Route, sample: Any) -> list[Derived]:
        """The Foxglove messages a checked sample makes (see the module's table)."""
        kind, topics = route.kind, route.topics
        if not kind or not isinstance(sample, dict):
            return []
        if kind == "fix":
            unit = topics[0][0].split("/")[-2]
            located = self._gnss_location(sample, unit)
            status = Derived(topics[1][0], "GnssStatus",
                             self.gnss_status(sample, unit, None if located is None else located[1]))
            return [status] if located is None else [Derived(topics[0][0], "LocationFix", located[0]), status]
        if kind == "ntrip":
            return [Derived(topics[0][0], "NtripStatus", ntrip_status(sample))]
        if kind == "estimator":
            self.remember(route, sample)
            return self._pose_messages(sample, topics, CAR_FRAME, valid=sample.get("position_valid") is True)
        if kind == "path":
            return self._route_messages(sample, topics)
        if kind == "truth":
            return self._pose_messages(sample, topics, TRUTH_FRAME, valid=True)
        return [Derived(topics[0][0], "Log", log) for log in self.health_logs(route.key, sample)]

    def remember(self, route: Route, sample: Any) -> None:
        """Keep what later samples need of a checked sample whose own messages nobody
        watches (STATEFUL_KINDS): the estimator's origin; a service's error counts."""
        if route.kind == "estimator" and isinstance(sample, dict):
            if sample.get("position_valid") is True and sample.get("origin") is not None:
                self._origin = tuple(sample["origin"])
        elif route.kind == "health" and isinstance(sample, dict):
            self.health_logs(route.key, sample)

    def gnss_location(self, fix: dict, unit: str) -> LocationFix | None:
        """A valid fix as the antenna's LocationFix, its sigmas as an ENU covariance."""
        located = self._gnss_location(fix, unit)
        return None if located is None else located[0]

    def _gnss_location(self, fix: dict, unit: str) -> tuple[LocationFix, list[float]] | None:
        """The LocationFix of a valid fix, and its covariance (the message keeps it unreadable)."""
        if not fix["valid"] or tuple(fix["ecef_m"]) == NO_FIX_ECEF:
            return None
        lat, lon, h = fix["lat_deg"], fix["lon_deg"], fix["height_m"]
        frame = self._frame(unit, fix["ecef_m"], lat, lon, h)
        enu_sigma = fix.get("enu_sigma_m")
        if enu_sigma is None and fix.get("sigma_h_m") is not None and fix.get("sigma_v_m") is not None:
            enu_sigma = (fix["sigma_h_m"], fix["sigma_h_m"], fix["sigma_v_m"])
        if enu_sigma is not None:           # the receiver's own sigmas, squared as they came
            cov = [enu_sigma[0] ** 2, 0.0, 0.0, 0.0, enu_sigma[1] ** 2, 0.0, 0.0, 0.0, enu_sigma[2] ** 2]
            # NMEA sends no sigmas: its are DOPs times a guessed range error
            cov_type = (LocationFixPositionCovarianceType.Approximated if fix.get("protocol") == "nmea"
                        else LocationFixPositionCovarianceType.DiagonalKnown)
        else:                                # ECEF sigmas, their cross terms unknown
            cov = [float(v) for v in frame.cov_to_enu(fix["ecef_sigma_m"]).ravel()]
            cov_type = LocationFixPositionCovarianceType.Approximated
        vel = fix.get("vel_ecef_mps")
        velocity = None if vel is None else _vector(frame.vector_to_enu(vel))
        colour = self._colours.setdefault(unit, GNSS_COLOURS[len(self._colours) % len(GNSS_COLOURS)])
        return LocationFix(timestamp=timestamp(fix["t"]), frame_id=unit, latitude=lat, longitude=lon,
                           altitude=h, position_covariance=cov, position_covariance_type=cov_type,
                           velocity=velocity, color=colour), cov

    @staticmethod
    def gnss_status(fix: dict, unit: str, enu_cov: list[float] | None = None) -> dict:
        """What a fix says of its solution (any fix, valid or not), as a GNSS_STATUS
        message without its nil fields; the sigmas from its location's ENU covariance."""
        pos_type = str(fix.get("pos_type") or "SINGLE")
        kind = solution_kind(pos_type)
        status = {"t": fix["t"], "unit": unit, "valid": fix["valid"] is True,
                  "pos_status": str(fix.get("pos_status") or ""), "pos_type": pos_type, "kind": kind,
                  "kind_level": solution_rank(kind), "sats_used": fix.get("sats_used"),
                  "sats_tracked": fix.get("sats_tracked"), "sol_age_s": number(fix.get("sol_age_s"))}
        if kind not in ("none", "single"):          # a single solution's diff age (0) says nothing
            status.update(diff_age_s=number(fix.get("diff_age_s")), base_id=fix.get("base_id") or None)
        if enu_cov is not None:
            status.update(sigma_h_m=math.sqrt(max(enu_cov[0], enu_cov[4])), sigma_v_m=math.sqrt(enu_cov[8]))
        words = [f"{pos_type} ({kind})"]
        if status.get("diff_age_s") is not None:
            words.append(f"diff age {status['diff_age_s']:.1f} s")
        if status.get("base_id"):
            words.append(f"base {status['base_id']}")
        if status["sats_used"] is not None:
            words.append(f"{status['sats_used']}/{status['sats_tracked']} sats")
        if status.get("sigma_h_m") is not None:
            words.append(f"sigma {status['sigma_h_m']:.3f} m")
        status["text"] = ", ".join(words)
        return {k: v for k, v in status.items() if v is not None}

    def _frame(self, unit: str, ecef_m, lat: float, lon: float, h: float) -> LocalFrame:
        frame = self._frames.get(unit)
        if frame is None or _distance_sq(frame.enu_of_ecef(ecef_m)) > FRAME_REUSE_M ** 2:
            frame = self._frames[unit] = LocalFrame(lat, lon, h)
        return frame

    def _pose_messages(self, s: dict, topics: list[tuple[str, str]], child: str, valid: bool) -> list[Derived]:
        """LocationFix, PoseInFrame and FrameTransform of an estimator state or a truth."""
        if not valid:
            return []
        stamp = timestamp(s["t"])
        w, x, y, z = s["quat"]
        rotation = Quaternion(x=x, y=y, z=z, w=w)
        position = _vector(s["enu_m"])
        out = [Derived(topics[1][0], "PoseInFrame", PoseInFrame(
                   timestamp=stamp, frame_id=WORLD_FRAME, pose=Pose(position=position, orientation=rotation))),
               Derived(topics[2][0], "FrameTransform", FrameTransform(
                   timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=child,
                   translation=position, rotation=rotation))]
        if s.get("lat_deg") is not None and s.get("lon_deg") is not None:
            out.insert(0, Derived(topics[0][0], "LocationFix", self._car_location(s, stamp, child)))
        return out

    @staticmethod
    def _car_location(s: dict, stamp: Timestamp, frame: str) -> LocationFix:
        yaw = s["yaw_rad"] if "yaw_rad" in s else s["euler_rad"][0]
        heading = (-yaw) % (2 * math.pi)                  # clockwise from north
        cov = s.get("enu_cov_m2")
        if cov is not None:
            ee, en, eu, nn, nu, uu = cov
            matrix = [ee, en, eu, en, nn, nu, eu, nu, uu]
            cov_type = LocationFixPositionCovarianceType.Known
        else:
            matrix, cov_type = [0.0] * 9, LocationFixPositionCovarianceType.Unknown
        return LocationFix(timestamp=stamp, frame_id=frame, latitude=s["lat_deg"], longitude=s["lon_deg"],
                           altitude=s.get("height_m") or 0.0, position_covariance=matrix,
                           position_covariance_type=cov_type, heading=heading,
                           velocity=_vector(s["vel_enu_mps"]),
                           color=TRUTH_COLOUR if frame == TRUTH_FRAME else ESTIMATOR_COLOUR)

    def _route_messages(self, path: dict, topics: list[tuple[str, str]]) -> list[Derived]:
        """The route on the map and, once the estimator's origin is known, in `enu`;
        nothing for a path that is no line (the pilot sends none such)."""
        if len(path["lat_deg"]) != len(path["lon_deg"]) or len(path["lat_deg"]) < 2:
            return []
        out = [Derived(topics[0][0], "GeoJson", route_geojson(path))]
        if self._origin is not None:
            out.append(Derived(topics[1][0], "SceneUpdate", route_scene(path, self._origin)))
        return out

    def health_logs(self, key: str, health: dict) -> list[Log]:
        """A Log for each error counter of a service that grew since its last health
        (and, the first time a service is heard, for the errors it had already)."""
        name = health["service"] + (f"/{health['unit']}" if health.get("unit") else "")
        now = {str(k): v for k, v in health["errors"].items() if type(v) is int}
        before = self._errors.get(key)
        self._errors[key] = now
        last_error = (health.get("state") or {}).get("last_error")
        logs = []
        for error, total in sorted(now.items()):
            grown = total - (before or {}).get(error, 0)
            if grown <= 0:
                continue
            since = "since it started" if before is None else "in the last health period"
            text = f"{name}: {error} +{grown} {since} (total {total})"
            if last_error:
                text += f"; last error: {last_error}"
            logs.append(Log(timestamp=timestamp(health["t"]), level=LogLevel.Warning if before is None
                            else LogLevel.Error, message=text, name=name))
        return logs


def ntrip_status(state: dict) -> dict:
    """The NTRIP client's state (viena.ntrip.state/1) as an NTRIP_STATUS message without
    its nil fields: streaming or why not, how much, from which base, how fresh."""
    age = number(state.get("last_message_age_s"))
    streaming = state.get("state") == "streaming"
    said_messages = state.get("messages")
    messages: dict = said_messages if isinstance(said_messages, dict) else {}
    types = sorted(int(t) for t in messages if str(t).isdigit())
    status = {"t": state["t"], "caster": state["caster"], "mountpoint": state["mountpoint"],
              "state": state["state"], "connected": state["connected"] is True,
              "stale": not streaming or age is None or age > CORRECTIONS_STALE_S,
              "why": state.get("why") or None, "bytes_per_s": number(state.get("bytes_per_s")),
              "last_message_age_s": age, "next_attempt_s": number(state.get("next_attempt_s")),
              "base_id": state.get("base_id") or None, "types": types,
              "frames": sum(v for v in messages.values() if type(v) is int)}
    words = [f"{state['state']} {state['caster']}/{state['mountpoint']}"]
    if status["why"]:
        words[0] += f" ({status['why']})"
    if status["bytes_per_s"] is not None:
        words.append(f"{status['bytes_per_s']:.0f} B/s")
    if types:
        words.append("types " + ",".join(map(str, types)))
    if status["base_id"]:
        words.append(f"base {status['base_id']}")
    if age is not None:
        words.append(f"last message {age:.1f} s ago" + (" (STALE)" if age > CORRECTIONS_STALE_S else ""))
    status["text"] = ", ".join(words)
    return {k: v for k, v in status.items() if v is not None}


def _marked_checkpoints(count: int) -> list[int]:
    """Which checkpoints get a mark of their own: all, or of a long route the ends."""
    return list(range(count)) if count <= MAX_CHECKPOINT_MARKS else [0, count - 1]


def route_geojson(path: dict) -> GeoJson:
    """A viena.pilot.path/1 sample as GeoJSON for Foxglove's Map panel: a LineString
    through the checkpoints and a Point per checkpoint, named as Foxglove labels them
    (`properties.name`), coordinates [lon, lat] as GeoJSON orders them."""
    lats, lons, speeds = path["lat_deg"], path["lon_deg"], path["speeds_mps"]
    line = {"type": "Feature",
            "properties": {"name": f"route: {len(lats)} checkpoints, {path['length_m']:.0f} m",
                           "style": ROUTE_STYLE},
            "geometry": {"type": "LineString", "coordinates": [[lon, lat] for lat, lon in zip(lats, lons)]}}
    features = [line]
    last = len(lats) - 1
    for i in _marked_checkpoints(len(lats)):
        name = f"checkpoint {i}" + (" (start)" if i == 0 else " (end)" if i == last else "")
        if i < len(speeds) and speeds[i] is not None:
            name += f", {speeds[i]:.1f} m/s"
        features.append({"type": "Feature", "properties": {"name": name, "style": CHECKPOINT_STYLE},
                         "geometry": {"type": "Point", "coordinates": [lons[i], lats[i]]}})
    return GeoJson(geojson=json.dumps({"type": "FeatureCollection", "features": features},
                                      separators=(",", ":"), allow_nan=False))


def route_scene(path: dict, origin: tuple[float, float, float]) -> SceneUpdate:
    """The route as a line (and its checkpoints as spheres) in frame `enu` at the
    estimator's origin, on the origin's level plane (checkpoints have no height), as the
    pilot sees it (services/pilot/model/path.py). One entity, replaced by the next."""
    east, north = checkpoints_enu(path["lat_deg"], path["lon_deg"], origin).T
    points = [Point3(x=float(e), y=float(n), z=0.0) for e, n in zip(east, north)]
    size = Vector3(x=CHECKPOINT_SIZE_M, y=CHECKPOINT_SIZE_M, z=CHECKPOINT_SIZE_M)
    spheres = [SpherePrimitive(pose=Pose(position=Vector3(x=float(east[i]), y=float(north[i]), z=0.0),
                                         orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                               size=size, color=ROUTE_COLOUR)
               for i in _marked_checkpoints(len(points))]
    line = LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=4.0, scale_invariant=True,
                         points=points, color=ROUTE_COLOUR)
    return SceneUpdate(entities=[SceneEntity(timestamp=timestamp(path["t"]), frame_id=WORLD_FRAME,
                                             id=ROUTE_ENTITY, lines=[line], spheres=spheres)])


#: the topics whose samples make Foxglove messages, and what kind of conversion each takes
DERIVED_KINDS = {topics.GNSS_FIX: "fix", topics.ESTIMATOR_STATE: "estimator", topics.SIM_TRUTH: "truth",
                 topics.HEALTH: "health", topics.PILOT_PATH: "path", topics.NTRIP_STATE: "ntrip"}


def _derived_kind(schema: Schema | None) -> str:
    """By the topic the schema travels on (common/samples/topics.py)."""
    topic = topics.BY_SCHEMA.get(schema.name) if schema is not None else None
    return DERIVED_KINDS.get(topic, "") if topic is not None else ""


def _vector(xyz) -> Vector3:
    return Vector3(x=xyz[0], y=xyz[1], z=xyz[2])


def _distance_sq(enu) -> float:
    return enu[0] ** 2 + enu[1] ** 2 + enu[2] ** 2

