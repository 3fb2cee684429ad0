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
What a panel shows of a sample is up to the module that owns its schema (its
`monitor_view`, made of the pieces in viena.common.display): the monitor only lays it out.
"""
from __future__ import annotations

import argparse
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from viena.common.display import Alert, fmt_age
from viena.common.errors import InputError
from viena.common.health import HealthReport
from viena.common.keys import Keys
from viena.common.log import setup_logging
from viena.common.session import (stop_on_signals, add_common_arguments, car_name, load_settings_file,
                                  open_session, zenoh_config)
from viena.services.estimator.state import monitor_view as estimator_view
from viena.services.gnss.model.fix import monitor_view as gnss_view
from viena.services.imu.model.sample import monitor_view as imu_view
from viena.services.sim.model.truth import monitor_view as truth_view
from viena.services.steering.model.state import monitor_view as steering_view

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
    report: HealthReport | None = None      # what its health says, as of now


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
        health = self._aged(s.health, now, self.health_stale_s)
        report = None if health is None else HealthReport.of(health.value, health.age_s)
        return ServiceView(s.name, status, since, health, report)


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


def _styled(text: str, style: str = "") -> tuple[str, str]:
    """A cell from a schema module's view: an Alert is red, whatever the row's style."""
    return (text, "red") if isinstance(text, Alert) else (text, style)


def _service_rows(view: View) -> Grid:
    columns = list(HealthReport().cells())          # what common/health.py shows of a report
    grid = Grid("services", "service", "status", *columns, "health age")
    for s in view.services:
        style = {"alive": "green", "lost": "bold red", "no token": "yellow"}[s.status]
        status = s.status if s.status_age_s is None or s.status == "alive" else f"{s.status} {fmt_age(s.status_age_s)}"
        stale = "yellow" if s.health is not None and s.health.stale else ""
        cells = (s.report or HealthReport()).cells()
        grid.add(s.name, (status, style), *(_styled(cells.get(c, "-"), stale) for c in columns),
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
        grid.add(unit, *(_styled(cells[unit].get(c, "-"), style) for c in columns), _rate(aged),
                 _age_cell(aged))
    return grid


def _field_rows(title: str, aged: Aged, cells: dict[str, str], per_row: int = 4) -> Grid:
    """A sample with many fields (the steering state) as name/value pairs, a few a line."""
    style = "dim" if aged.stale else ""
    pairs = [("age", _age_cell(aged)), ("Hz", (_rate(aged), "")),
             *((name, _styled(value, style)) for name, value in cells.items())]
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
        grids.append(_sample_rows("GNSS", view.gnss, gnss_view, "unit"))
    if view.imu:
        grids.append(_sample_rows("IMU", view.imu, imu_view, "unit"))
    if view.steering:
        grids.append(_field_rows("steering", view.steering, steering_view(view.steering.value)))
    if view.estimator:
        grids.append(_sample_rows("estimator", {"state": view.estimator}, estimator_view, ""))
    if view.truth:
        grids.append(_sample_rows("simulator truth", {"truth": view.truth}, truth_view, ""))
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
