"""`viena monitor`: a live dashboard of the whole car, refreshed a few times a second.

Services are found by their liveliness tokens (viena/<car>/alive/<service>[/<unit>]);
each shows its health (rates, errors, last-sample age, reconnects). Below them: the GNSS
fixes, the IMUs, the steering, the estimator and the simulator's truth, then any other
key. A service whose token disappears is shown as lost (at once when it stops; when it
crashes, once zenoh's lease expires, 10 s by default); every value carries its age,
and a value older than --stale seconds (health: three periods) is marked stale, not
shown as current. A service heard only through its health, with no token (a replayed
drive), is shown as "no token". For one key, `viena sub` prints every sample.

The dashboard is a plain data model (`MonitorModel`, fed with decoded samples) and a
rich rendering of its `view()`; only the newest payload per key is decoded, once a frame.
"""
from __future__ import annotations

import argparse
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from viena.common.errors import InputError
from viena.common.health import RECONNECTS
from viena.common.keys import Keys
from viena.common.log import setup_logging
from viena.common.session import (stop_on_signals, add_common_arguments, car_name, load_settings_file,
                                  open_session, zenoh_config)

DATA_STALE_S = 1.0
HEALTH_STALE_S = 3.0            # health comes once a second: three missed is stale
REFRESH_HZ = 4.0
RATE_WINDOW_S = 1.0
POLL_S = 0.02                   # how often arrivals are taken (and so stamped)


# -- the data model ---------------------------------------------------------------------------
@dataclass
class Latest:
    """The newest sample on one key."""

    key: str
    value: dict
    schema: str
    received: float                 # monotonic s
    count: int = 1                  # samples seen on the key
    rate_hz: float | None = None
    rate_mark: tuple[float, int] = (0.0, 0)     # (time, count) the rate is measured from


@dataclass
class ServiceState:
    name: str                       # "gnss/gnss0", "sim"
    token: bool | None = None       # None: never seen a token
    token_changed: float | None = None
    health: Latest | None = None


@dataclass
class Aged:
    """A value with its age, as the view shows it."""

    value: dict
    age_s: float
    stale: bool
    rate_hz: float | None = None
    key: str = ""
    schema: str = ""


@dataclass
class ServiceView:
    name: str
    status: str                     # alive | lost | no token
    status_age_s: float | None      # since the token came or went
    health: Aged | None
    uptime_s: float | None = None
    rates_hz: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    last_sample_age_s: float | None = None
    reconnects: int | None = None
    state: dict = field(default_factory=dict)


@dataclass
class View:
    car: str
    services: list[ServiceView]
    gnss: dict[str, Aged]
    imu: dict[str, Aged]
    steering: Aged | None
    estimator: Aged | None
    truth: Aged | None
    others: list[Aged]
    bad: dict[str, str]             # key -> why its last sample could not be decoded
    total_rate_hz: float


def _number(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def _vec(v, n: int | None = None) -> list[float] | None:
    if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n) or not v:
        return None
    out = [_number(x) for x in v]
    return None if any(x is None for x in out) else out


class MonitorModel:
    """What the dashboard knows: tokens, the newest sample per key, their ages.

    Feed it `token(key, alive, now)` and `sample(key, value, now, schema)`; read `view(now)`.
    Times are monotonic seconds, so a test can drive it with its own clock.
    """

    def __init__(self, car: str = "elettra", data_stale_s: float = DATA_STALE_S,
                 health_stale_s: float = HEALTH_STALE_S):
        self.keys = Keys(car)
        self.data_stale_s, self.health_stale_s = data_stale_s, health_stale_s
        self.services: dict[str, ServiceState] = {}
        self.latest: dict[str, Latest] = {}
        self.bad: dict[str, str] = {}

    # -- feeding --------------------------------------------------------------------------
    def _local(self, key: str) -> list[str] | None:
        prefix = self.keys.prefix + "/"
        return key[len(prefix):].split("/") if key.startswith(prefix) else None

    def _service(self, name: str) -> ServiceState:
        return self.services.setdefault(name, ServiceState(name))

    def token(self, key: str, alive: bool, now: float) -> None:
        parts = self._local(key)
        if not parts or parts[0] != "alive" or len(parts) < 2:
            return
        service = self._service("/".join(parts[1:]))
        if service.token != alive:
            service.token, service.token_changed = alive, now

    def sample(self, key: str, value: Any, now: float, schema: str = "",
               count: int | None = None) -> None:
        """The newest sample on `key`; `count` is the total seen on it (default: one more)."""
        parts = self._local(key)
        if parts is None:
            return
        if not isinstance(value, dict):
            value = {"value": value}
        self.bad.pop(key, None)
        latest = self.latest.get(key)
        if latest is None:
            n = count or 1
            latest = self.latest[key] = Latest(key, value, schema, now, n, rate_mark=(now, n))
        else:
            latest.value, latest.schema, latest.received = value, schema, now
            latest.count = count if count is not None else latest.count + 1
        t_mark, n_mark = latest.rate_mark
        if now - t_mark >= RATE_WINDOW_S:
            latest.rate_hz = (latest.count - n_mark) / (now - t_mark)
            latest.rate_mark = (now, latest.count)
        if parts[-1] == "health" and len(parts) >= 2:
            self._service("/".join(parts[:-1])).health = latest

    def bad_sample(self, key: str, why: str) -> None:
        self.bad[key] = why

    # -- reading --------------------------------------------------------------------------
    def _aged(self, latest: Latest | None, now: float, stale_s: float | None = None) -> Aged | None:
        if latest is None:
            return None
        age = max(0.0, now - latest.received)
        rate = latest.rate_hz
        if rate is not None and now - latest.rate_mark[0] > 2 * RATE_WINDOW_S:
            rate = 0.0                      # nothing came in the last window
        return Aged(latest.value, age, age > (stale_s or self.data_stale_s), rate,
                    latest.key, latest.schema)

    def view(self, now: float) -> View:
        services = [self._service_view(s, now) for _, s in sorted(self.services.items())]
        gnss, imu, others = {}, {}, []
        steering = estimator = truth = None
        for key, latest in sorted(self.latest.items()):
            parts = self._local(key)
            aged = self._aged(latest, now)
            if parts[-1] == "health":
                continue
            if len(parts) == 3 and parts[0] == "gnss" and parts[2] == "fix":
                gnss[parts[1]] = aged
            elif len(parts) == 3 and parts[0] == "imu" and parts[2] == "sample":
                imu[parts[1]] = aged
            elif parts == ["steering", "state"]:
                steering = aged
            elif parts == ["estimator", "state"]:
                estimator = aged
            elif parts == ["sim", "truth"]:
                truth = aged
            else:
                others.append(aged)
        total = sum(a.rate_hz or 0.0 for a in (self._aged(x, now) for x in self.latest.values()))
        return View(self.keys.car, services, gnss, imu, steering, estimator, truth, others,
                    dict(self.bad), total)

    def _service_view(self, s: ServiceState, now: float) -> ServiceView:
        status = {True: "alive", False: "lost", None: "no token"}[s.token]
        since = None if s.token_changed is None else now - s.token_changed
        view = ServiceView(s.name, status, since, self._aged(s.health, now, self.health_stale_s))
        if view.health is None:
            return view
        h, age = view.health.value, view.health.age_s
        view.uptime_s = _plus(_number(h.get("uptime_s")), age)
        counts = _numbers(h.get("counts"))
        # a rate of something that never happened (unknown_messages 0.0) is only noise
        view.rates_hz = {k: v for k, v in _numbers(h.get("rates_hz")).items() if v or counts.get(k)}
        view.errors = {k: v for k, v in _numbers(h.get("errors")).items() if v}
        # as the service reported it: the health's own age says how old that report is
        view.last_sample_age_s = _number(h.get("last_sample_age_s"))
        view.state = h.get("state") if isinstance(h.get("state"), dict) else {}
        # device services count them under one name (common/health.py); others have none
        reconnects = counts.get(RECONNECTS)
        view.reconnects = None if reconnects is None else int(reconnects)
        return view


def _plus(value: float | None, age: float) -> float | None:
    """A duration reported `age` seconds ago, as it is now."""
    return None if value is None else value + age


def _numbers(v) -> dict[str, float]:
    if not isinstance(v, dict):
        return {}
    return {str(k): n for k, x in v.items() if (n := _number(x)) is not None}


# -- formatting (plain text pieces; rich only arranges them) ----------------------------------
def fmt_age(age: float | None) -> str:
    if age is None:
        return "-"
    if age < 10:
        return f"{age:.2f} s"
    if age < 120:
        return f"{age:.0f} s"
    return f"{age / 60:.0f} min"


def fmt_num(v, digits: int = 3) -> str:
    """A scalar for a cell: ints as they are, floats to `digits` places, None as '-'."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.{digits}f}" if v == 0 or 1e-3 <= abs(v) < 1e6 else f"{v:.{digits}g}"
    return str(v)[:40] or "-"


def fmt_vec(v, digits: int = 2, scale: float = 1.0) -> str:
    vec = _vec(v)
    if vec is None:
        return "-"
    return "[" + " ".join(f"{x * scale:.{digits}f}" for x in vec) + "]"


def fmt_deg(rad) -> str:
    n = _number(rad)
    return "-" if n is None else f"{math.degrees(n):.1f}°"


def fmt_map(values: dict, digits: int = 1, limit: int = 6) -> str:
    items = [f"{k} {fmt_num(v, digits)}" for k, v in list(values.items())[:limit]]
    if len(values) > limit:
        items.append(f"+{len(values) - limit}")
    return ", ".join(items) or "-"


def gnss_cells(fix: dict) -> dict[str, str]:
    sigma = _vec(fix.get("ecef_sigma_m"), 3)
    status = "/".join(str(fix[k]) for k in ("pos_status", "pos_type") if fix.get(k) is not None)
    return {
        "fix": ("valid" if fix.get("valid") is True else "NO FIX" if fix.get("valid") is False else "?"),
        "status": status or "-",
        "sats": f"{fmt_num(fix.get('sats_used'))}/{fmt_num(fix.get('sats_tracked'))}",
        "sigma": "-" if sigma is None else f"{math.sqrt(sum(x * x for x in sigma)):.2f} m",
        "position": ("-" if _number(fix.get("lat_deg")) is None else
                     f"{fmt_num(fix.get('lat_deg'), 7)}, {fmt_num(fix.get('lon_deg'), 7)}, "
                     f"{fmt_num(fix.get('height_m'), 1)} m"),
        "latency": "-" if _number(fix.get("latency_s")) is None else f"{fix['latency_s'] * 1e3:.0f} ms",
    }


def imu_cells(s: dict) -> dict[str, str]:
    mag = _vec(s.get("mag_T"), 3)
    return {
        "accel m/s²": fmt_vec(s.get("accel_mps2")),
        "gyro °/s": fmt_vec(s.get("gyro_radps"), 1, 180 / math.pi),
        "|mag| µT": "-" if mag is None else f"{math.sqrt(sum(x * x for x in mag)) * 1e6:.1f}",
        "seq": fmt_num(s.get("seq")),
    }


def estimator_cells(s: dict) -> dict[str, str]:
    var = _vec(s.get("enu_var_m2"), 3)
    att = _vec(s.get("att_var_rad2"), 3)
    cells = {
        "mode": str(s.get("mode", "-")),
        "position ENU m": fmt_vec(s.get("enu_m")),
        "σ pos": "-" if var is None else f"{math.sqrt(max(var[0], 0) + max(var[1], 0)):.2f} m",
        "speed": "-" if _number(s.get("speed_mps")) is None else f"{s['speed_mps']:.2f} m/s",
        "yaw": fmt_deg(s.get("yaw_rad")) + ("" if att is None else f" ± {math.degrees(math.sqrt(max(att[0], 0))):.1f}°"),
        "heading": f"{s.get('heading_source', '-')}" + ("" if s.get("heading_valid") is not False else " (not valid)"),
        "gnss used": fmt_num(s.get("gnss_used")),
    }
    if s.get("waypoint") is not None:
        cells["waypoint"] = (f"{fmt_num(s.get('wp_distance_m'), 1)} m at {fmt_num(s.get('wp_bearing_deg'), 1)}°, "
                             f"turn {fmt_num(s.get('wp_heading_error_deg'), 1)}°")
    return cells


def truth_cells(s: dict) -> dict[str, str]:
    euler = _vec(s.get("euler_rad"), 3)
    return {
        "position ENU m": fmt_vec(s.get("enu_m")),
        "speed": "-" if _number(s.get("speed_mps")) is None else f"{s['speed_mps']:.2f} m/s",
        "yaw": "-" if euler is None else fmt_deg(euler[0]),
        "wheel": fmt_deg(s.get("wheel_angle_rad")),
    }


#: steering state fields shown first when present; the rest follow as they come
STEERING_FIRST = ("phase", "armed", "owner", "angle_deg", "target_deg", "goal_deg", "watchdog",
                  "trip", "fault", "drive_heartbeat", "ds402", "decision", "limits")


def generic_cells(s: dict, first=()) -> dict[str, str]:
    """Any sample's top-level fields: angles in degrees, maps on one line."""
    names = [k for k in first if k in s] + [k for k in s if k not in first and k not in ("t", "seq")]
    cells = {}
    for name in names:
        v = s[name]
        if isinstance(name, str) and name.endswith("_rad") and _number(v) is not None:
            cells[name[:-4] + " °"] = f"{math.degrees(v):.2f}"
        elif isinstance(v, dict):
            cells[str(name)] = fmt_map(v, 2) if v else "-"
        elif isinstance(v, (list, tuple)):
            cells[str(name)] = fmt_vec(v, 3) if _vec(v) else (", ".join(map(str, v))[:40] or "-")
        else:
            cells[str(name)] = fmt_num(v)
    return cells


def generic_state(state: dict, limit: int = 3) -> str:
    cells = list(generic_cells(state).items())
    text = ", ".join(f"{k} {v}" for k, v in cells[:limit])
    return (text + (f" +{len(cells) - limit}" if len(cells) > limit else "")) or "-"


# -- rendering -------------------------------------------------------------------------------
class Grid:
    """A titled table drawn as aligned text.

    rich's Table measures and wraps every cell on every frame, which costs more CPU than
    the rest of the monitor together; values here are short, so columns just align.
    """

    def __init__(self, title: str, *headers: str):
        self.title, self.headers = title, headers
        self.rows: list[list[tuple[str, str]]] = []

    def add(self, *cells) -> None:
        """Cells are text, or (text, rich style)."""
        self.rows.append([c if isinstance(c, tuple) else (str(c), "") for c in cells])

    def text(self):
        from rich.text import Text

        widths = [max([len(h), *(len(row[i][0]) for row in self.rows if i < len(row))])
                  for i, h in enumerate(self.headers)]
        out = Text(no_wrap=True, overflow="ellipsis", end="")
        out.append(f"\n{self.title}\n", style="bold")
        if any(self.headers):
            out.append("  ".join(h.ljust(w) for h, w in zip(self.headers, widths)).rstrip() + "\n",
                       style="underline")
        for row in self.rows:
            for i, ((cell, style), width) in enumerate(zip(row, widths)):
                out.append(cell.ljust(width) if i < len(widths) - 1 else cell, style=style)
                if i < len(widths) - 1:
                    out.append("  ")
            out.append("\n")
        return out


def _age_cell(aged: Aged | None) -> tuple[str, str]:
    if aged is None:
        return "-", "dim"
    if aged.stale:
        return f"STALE {fmt_age(aged.age_s)}", "bold yellow"
    return fmt_age(aged.age_s), "green"


def _rate(aged: Aged | None) -> str:
    return "-" if aged is None or aged.rate_hz is None else f"{aged.rate_hz:.1f}"


def _service_rows(view: View) -> Grid:
    grid = Grid("services", "service", "status", "up", "rates Hz", "errors", "last sample",
                "reconnects", "state", "health age")
    for s in view.services:
        style = {"alive": "green", "lost": "bold red", "no token": "yellow"}[s.status]
        status = s.status if s.status_age_s is None or s.status == "alive" else f"{s.status} {fmt_age(s.status_age_s)}"
        stale = s.health is not None and s.health.stale
        grid.add(s.name, (status, style), fmt_age(s.uptime_s), fmt_map(s.rates_hz),
                 (fmt_map(s.errors, 0), "red" if s.errors else ""),
                 (fmt_age(s.last_sample_age_s), "yellow" if stale else ""),
                 "-" if s.reconnects is None else str(s.reconnects), generic_state(s.state),
                 _age_cell(s.health))
    if not view.services:
        grid.add(("no service seen yet", "dim"))
    return grid


def _sample_rows(title: str, rows: dict[str, Aged], cells_of, label: str) -> Grid:
    """One row per unit; columns are whatever the cells of any row name."""
    cells = {unit: cells_of(aged.value) for unit, aged in rows.items()}
    columns = list(dict.fromkeys(c for row in cells.values() for c in row))
    grid = Grid(title, label, *columns, "Hz", "age")
    for unit, aged in rows.items():
        style = "dim" if aged.stale else ""
        grid.add(unit, *((cells[unit].get(c, "-"), style) for c in columns), _rate(aged),
                 _age_cell(aged))
    return grid


def _field_rows(title: str, aged: Aged, cells: dict[str, str], per_row: int = 4) -> Grid:
    """A sample with many fields (the steering state) as name/value pairs, a few a line."""
    style = "dim" if aged.stale else ""
    pairs = [("age", _age_cell(aged)), ("Hz", (_rate(aged), "")),
             *((name, (value, style)) for name, value in cells.items())]
    grid = Grid(title, *([""] * (2 * per_row)))
    for i in range(0, len(pairs), per_row):
        grid.add(*(cell for name, value in pairs[i:i + per_row] for cell in ((name, "bold"), value)))
    return grid


def render(view: View, title: str = ""):
    """The view as one rich renderable."""
    from rich.console import Group
    from rich.text import Text

    grids = [_service_rows(view)]
    if view.gnss:
        grids.append(_sample_rows("GNSS", view.gnss, gnss_cells, "unit"))
    if view.imu:
        grids.append(_sample_rows("IMU", view.imu, imu_cells, "unit"))
    if view.steering:
        grids.append(_field_rows("steering", view.steering,
                                 generic_cells(view.steering.value, STEERING_FIRST)))
    if view.estimator:
        grids.append(_sample_rows("estimator", {"state": view.estimator}, estimator_cells, ""))
    if view.truth:
        grids.append(_sample_rows("simulator truth", {"truth": view.truth}, truth_cells, ""))
    if view.others or view.bad:
        others = Grid("other keys", "key", "schema", "Hz", "age")
        for aged in view.others:
            others.add(aged.key, aged.schema or "-", _rate(aged), _age_cell(aged))
        for key, why in sorted(view.bad.items()):
            others.add(key, (f"undecodable: {why}"[:80], "red"), "-", "-")
        grids.append(others)
    heading = title or f"viena monitor · car {view.car} · {view.total_rate_hz:.0f} samples/s"
    return Group(Text(heading, style="bold reverse", no_wrap=True, overflow="ellipsis"),
                 *(g.text() for g in grids))


# -- zenoh glue -------------------------------------------------------------------------------
class LiveFeed:
    """Keeps only the newest payload and a count per key, plus the liveliness events;
    `apply(model)` decodes what changed and feeds the model.

    Samples wait in a ring channel inside zenoh and are taken by `poll()` from the main
    thread, so zenoh's threads never wait for the GIL while a frame is drawn; the ring
    drops the oldest samples rather than grow if the monitor stalls.
    """

    RING = 8192

    def __init__(self):
        self._lock = threading.Lock()
        self._newest: dict[str, tuple[bytes, str, float]] = {}
        self._counts: dict[str, int] = {}
        self._tokens: queue.SimpleQueue = queue.SimpleQueue()
        self._ring = None

    def subscribe(self, session, keys: Keys) -> list:
        """Declare what the dashboard needs; returns the entities to undeclare."""
        import zenoh

        self._ring = session.declare_subscriber(keys.all, zenoh.handlers.RingChannel(self.RING))
        tokens = session.liveliness().declare_subscriber(keys.key("alive", "**"), self.on_token,
                                                         history=True)
        return [self._ring, tokens]

    def poll(self) -> None:
        """Take what the ring channel holds (call it often: it stamps the arrival)."""
        while (sample := self._ring.try_recv()) is not None:
            self.on_sample(sample)

    def on_sample(self, sample) -> None:
        key, now = str(sample.key_expr), time.monotonic()
        with self._lock:
            self._newest[key] = (sample.payload.to_bytes(), str(sample.encoding), now)
            self._counts[key] = self._counts.get(key, 0) + 1

    def on_token(self, sample) -> None:
        import zenoh

        self._tokens.put((str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, time.monotonic()))

    def apply(self, model: MonitorModel) -> None:
        from viena.sub import decode_sample

        while True:
            try:
                key, alive, now = self._tokens.get_nowait()
            except queue.Empty:
                break
            model.token(key, alive, now)
        with self._lock:
            newest, self._newest = self._newest, {}
            counts = dict(self._counts)
        for key, (payload, encoding, received) in newest.items():
            schema = encoding.split(";", 1)[1] if ";" in encoding else ""
            try:
                value = decode_sample(payload, encoding)
            except (InputError, ValueError) as exc:
                model.bad_sample(key, str(exc))
                continue
            model.sample(key, value, received, schema, counts[key])


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena monitor", description=__doc__)
    parser.add_argument("--refresh", type=float, default=REFRESH_HZ, metavar="HZ",
                        help=f"screen refreshes per second (default {REFRESH_HZ:g})")
    parser.add_argument("--stale", type=float, default=DATA_STALE_S, metavar="S",
                        help=f"mark a value stale after S seconds (default {DATA_STALE_S:g}; "
                             f"health after {HEALTH_STALE_S:g})")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="exit after S seconds (default: until Ctrl-C)")
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    setup_logging("WARNING" if args.log_level == "INFO" else args.log_level)
    try:
        toml = load_settings_file(args)
        conf = zenoh_config(args, toml)
        model = MonitorModel(car_name(args, toml), data_stale_s=args.stale)
        if args.refresh <= 0:
            raise InputError("--refresh must be > 0")
    except (InputError, ValueError) as exc:
        print(f"viena monitor: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    session = open_session(conf, stop)
    if session is None:
        return 0
    feed = LiveFeed()
    keys = model.keys
    declared = feed.subscribe(session, keys)
    where = ", ".join(args.connect or []) or "the configured router"
    console = Console()
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    period = 1.0 / args.refresh
    try:
        with Live(console=console, auto_refresh=False, screen=console.is_terminal,
                  redirect_stderr=False) as live:
            next_frame = time.monotonic()
            while not stop.is_set():
                feed.poll()
                now = time.monotonic()
                if now >= next_frame:
                    next_frame = now + period
                    feed.apply(model)
                    view = model.view(now)
                    live.update(render(view, f"viena monitor · car {view.car} · {where} · "
                                             f"{time.strftime('%H:%M:%S')} · "
                                             f"{view.total_rate_hz:.0f} samples/s"), refresh=True)
                    if deadline is not None and now >= deadline:
                        break
                stop.wait(POLL_S)
    finally:
        for entity in declared:
            try:
                entity.undeclare()
            except Exception:
                pass
        session.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
