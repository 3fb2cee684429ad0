"""`viena monitor`: a live dashboard of the whole car, refreshed a few times a second.

Services are found by their liveliness tokens (viena/<car>/alive/<service>[/<unit>]);
each shows its health (rates, errors, last-sample age, reconnects). Below them: the GNSS
fixes (each receiver's solution type and the age of its corrections), the NTRIP client
(streaming or why not, bytes a second, the last message's age) and the corrections on the
bus, the IMUs, the steering, the estimator, the pilot (its mode, cross-track, and the way
to its next checkpoint) and the simulator's truth, then any other key. A service whose
token disappears is shown as lost (at once when it stops; when it crashes, once zenoh's
lease expires, 10 s by default); every value carries its age, and a value older than
--stale seconds (health: three periods) is marked stale, not shown as current. A service
heard only through its health, with no token (a replayed drive), is shown as "no token".
For one key, `viena sub` prints every sample.

The dashboard is a plain data model (`MonitorModel`, fed with decoded samples) and a
rich rendering of its `view()` as tables that wrap rather than cut a value short at any
width; only the newest payload per key is decoded, once a frame. What a panel shows of a
sample is up to the module that owns its schema (its `monitor_view`, made of the pieces in
viena.common.display): the monitor only lays it out, and colours what asks to be noticed:
an Alert, and the words the car uses for trouble (NO FIX, tripped, fault, lost) in red,
stale values in yellow; corrections older than CORRECTIONS_STALE_S (common/display.py) are red. A service's
error totals stay on screen but are red only while they grow: the column "errors/s" is
their rate over the last RECENT_ERRORS_S. Until the router answers, the screen says which
endpoint cannot be reached and why.
"""
from __future__ import annotations

import argparse
import queue
import re
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from viena.common.display import Alert, fmt_age, fmt_map
from viena.common.errors import InputError
from viena.common.keys import Keys
from viena.common.samples import topics
from viena.common.samples.corrections import monitor_view as corrections_view
from viena.common.samples.estimator import monitor_view as estimator_view
from viena.common.samples.fix import monitor_view as gnss_view
from viena.common.samples.health import HealthReport
from viena.common.samples.imu import monitor_view as imu_view
from viena.common.samples.ntrip import monitor_view as ntrip_view
from viena.common.samples.pilot import monitor_view as pilot_view
from viena.common.samples.steering import monitor_view as steering_view
from viena.common.samples.topics import Topic
from viena.common.samples.truth import monitor_view as truth_view
from viena.common.session import add_common_arguments, config_endpoints
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, add_timeout_flag, guarded, tool_logging

DATA_STALE_S = 1.0
HEALTH_STALE_S = 3.0            # health comes once a second: three missed is stale
REFRESH_HZ = 4.0
RATE_WINDOW_S = 1.0
POLL_S = 0.02                   # how often arrivals are taken (and so stamped)
RECENT_ERRORS_S = 10.0          # errors/s is measured over this much of the latest health
#: corrections older than this are stale: the receivers are about to fall back to a coarser
#: solution (their RTK timeout is 60 s; float and fixed solutions degrade long before)
#: words a view uses for trouble: shown in red wherever they stand alone in a cell
ALARM_WORDS = re.compile(r"\b(NO FIX|tripped|FAULT|fault|lost)\b")


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
    #: (received, error totals) of its recent health samples, oldest first
    errors_seen: deque = field(default_factory=deque)


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
    error_rates: dict[str, float] = field(default_factory=dict)    # errors/s, recently


@dataclass
class View:
    car: str
    services: list[ServiceView]
    gnss: dict[str, Aged]
    ntrip: Aged | None
    corrections: Aged | None
    imu: dict[str, Aged]
    steering: Aged | None
    estimator: Aged | None
    pilot: Aged | None
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
    def _service(self, name: str) -> ServiceState:
        return self.services.setdefault(name, ServiceState(name))

    def token(self, key: str, alive: bool, now: float) -> None:
        found = self.keys.topic_of(key)
        if found is None or found[0] is not topics.ALIVE:
            return
        service = self._service(topics.process_name(found[1]))
        if service.token != alive:
            service.token, service.token_changed = alive, now

    def sample(self, key: str, value: Any, now: float, schema: str = "",
               count: int | None = None) -> None:
        """The newest sample on `key`; `count` is the total seen on it (default: one more)."""
        if self.keys.local(key) is None:
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
        found = self.keys.topic_of(key)
        if found is not None and found[0] is topics.HEALTH:
            service = self._service(topics.process_name(found[1]))
            service.health = latest
            service.errors_seen.append((now, HealthReport.of(value).errors))
            while len(service.errors_seen) > 2 and now - service.errors_seen[1][0] >= RECENT_ERRORS_S:
                service.errors_seen.popleft()

    def bad_sample(self, key: str, why: str) -> None:
        self.bad[key] = why

    # -- reading --------------------------------------------------------------------------
    def _aged(self, latest: Latest, now: float, stale_s: float | None = None) -> Aged:
        age = max(0.0, now - latest.received)
        rate = latest.rate_hz
        if rate is not None and now - latest.rate_mark[0] > 2 * RATE_WINDOW_S:
            rate = 0.0                      # nothing came in the last window
        return Aged(latest.value, age, age > (stale_s or self.data_stale_s), rate,
                    latest.key, latest.schema)

    def view(self, now: float) -> View:
        services = [self._service_view(s, now) for _, s in sorted(self.services.items())]
        gnss: dict[str, Aged] = {}
        imu: dict[str, Aged] = {}
        others: list[Aged] = []
        #: the panel of each single-key topic (a View field); fixes and IMU samples go by unit
        panels: dict[Topic, Aged] = {}
        for key, latest in sorted(self.latest.items()):
            found = self.keys.topic_of(key)
            aged = self._aged(latest, now)
            topic, chunks = found if found is not None else (None, {})
            if topic is topics.HEALTH or topic is topics.INFO:     # health has its own rows; info says who
                continue
            if topic is topics.GNSS_FIX:
                gnss[topics.unit_in(chunks)] = aged
            elif topic is topics.IMU_SAMPLE:
                imu[topics.unit_in(chunks)] = aged
            elif topic in PANELS:
                panels[topic] = aged
            elif self.keys.local(key) is not None:              # `latest` holds the car's keys alone
                others.append(aged)
        steering, estimator, pilot, truth, ntrip, corrections = (panels.get(t) for t in PANELS)
        total = sum(a.rate_hz or 0.0 for a in (self._aged(x, now) for x in self.latest.values()))
        return View(self.keys.car, services, gnss, ntrip, corrections, imu, steering, estimator, pilot, truth,
                    others, dict(self.bad), total)

    def _service_view(self, s: ServiceState, now: float) -> ServiceView:
        status = {True: "alive", False: "lost", None: "no token"}[s.token]
        since = None if s.token_changed is None else now - s.token_changed
        health = None if s.health is None else self._aged(s.health, now, self.health_stale_s)
        report = None if health is None else HealthReport.of(health.value, health.age_s)
        return ServiceView(s.name, status, since, health, report, error_rates(s.errors_seen))


#: the monitor's panels of one key each, in the order View lists them
PANELS = (topics.STEERING_STATE, topics.ESTIMATOR_STATE, topics.PILOT_STATE, topics.SIM_TRUTH, topics.NTRIP_STATE,
          topics.GNSS_CORRECTIONS)


def error_rates(seen) -> dict[str, float]:
    """Errors per second between the oldest and the newest of (time, totals), for the
    errors that grew; a total that fell (the service restarted) counts from zero."""
    if len(seen) < 2:
        return {}
    (t0, first), (t1, last) = seen[0], seen[-1]
    if t1 <= t0:
        return {}
    rates = {}
    for name, total in last.items():
        grown = total - first.get(name, 0.0)
        grown = total if grown < 0 else grown
        if grown > 0:
            rates[name] = grown / (t1 - t0)
    return rates


# -- rendering -------------------------------------------------------------------------------
def _table(title: str, *headers: str, show_header: bool = True):
    """A titled table whose cells wrap (never cut) when the screen is narrow."""
    from rich import box
    from rich.table import Table

    table = Table(title=title, title_justify="left", title_style="bold", box=box.SIMPLE_HEAD,
                  show_header=show_header, show_edge=False, pad_edge=False, padding=(0, 1),
                  header_style="underline")
    for header in headers:
        table.add_column(header, overflow="fold")
    return table


def _cell(text: str, style: str = "", name: str = ""):
    """A cell of a view: an Alert, or a word of trouble (alone, or as the cell's name with
    a value), is red whatever the row's style."""
    from rich.text import Text

    if isinstance(text, Alert) or ALARM_WORDS.search(text) or (
            name and ALARM_WORDS.fullmatch(name) and text not in ("-", "", "ok", "no")):
        style = "bold red"
    return Text(text, style=style)


def _age_cell(aged: Aged | None):
    from rich.text import Text

    if aged is None:
        return Text("-", style="dim")
    if aged.stale:
        return Text(f"STALE {fmt_age(aged.age_s)}", style="bold yellow")
    return Text(fmt_age(aged.age_s), style="green")


def _rate(aged: Aged | None) -> str:
    return "-" if aged is None or aged.rate_hz is None else f"{aged.rate_hz:.1f}"


def _service_rows(view: View):
    from rich.text import Text

    columns = list(HealthReport().cells())          # what common/samples/health.py shows of a report
    table = _table("services", "service", "status", "errors/s", *columns, "health age")
    for s in view.services:
        style = {"alive": "green", "lost": "bold red", "no token": "yellow"}[s.status]
        status = s.status if s.status_age_s is None or s.status == "alive" else f"{s.status} {fmt_age(s.status_age_s)}"
        row_style = "yellow" if s.health is not None and s.health.stale else ""
        cells = (s.report or HealthReport()).cells()
        recent = (Text(fmt_map(s.error_rates, 2), style="bold red") if s.error_rates
                  else Text("-", style=row_style))
        # totals from the past stay readable but quiet; red is for errors happening now
        totals = [Text(cells.get(c, "-"), style="dim") if isinstance(cells.get(c), Alert) and not s.error_rates
                  else _cell(cells.get(c, "-"), row_style) for c in columns]
        table.add_row(s.name, Text(status, style=style), recent, *totals, _age_cell(s.health))
    if not view.services:
        table.add_row(Text("no service seen yet", style="dim"))
    return table


#: the widest an age cell grows ("STALE 1.10 s")
_AGE_WIDTH = 12
#: a cell this short is never wrapped ("NO FIX" stays on one line); a longer one wraps between words
_WHOLE_CELL = 12


def _narrowest(text: str) -> int:
    """The narrowest a cell is drawn readably: whole if short, else its longest word."""
    return max(min(len(text), _WHOLE_CELL), *(len(word) for word in text.split() or [""]))


def _sample_rows(title: str, rows: dict[str, Aged], cells_of, label: str, width: int | None = None):
    """One row per unit; columns are whatever the cells of any row name. A table that
    would not fit `width` columns with its short cells whole and the others wrapped
    between words (a receiver's ten columns on 80) becomes the name/value pairs of
    `_field_rows`, one block per unit."""
    from rich.console import Group

    cells = {unit: cells_of(aged.value) for unit, aged in rows.items()}
    columns = list(dict.fromkeys(c for row in cells.values() for c in row))
    texts = [[label, *rows], *([c, *(row.get(c, "-") for row in cells.values())] for c in columns)]
    narrowest = [max(map(_narrowest, column)) for column in texts] + [5, _AGE_WIDTH]
    if width is not None and sum(narrowest) + 2 * (len(narrowest) - 1) > width:
        per_row = max(1, min(4, width // 40))
        return Group(*(_field_rows(f"{title} {unit}".strip(), aged, cells[unit], per_row)
                       for unit, aged in rows.items()))
    table = _table(title, label, *columns, "Hz", "age")
    for column, text in zip(table.columns, texts):
        # a column of short cells is never wrapped: rich shrinks the others, between words
        column.no_wrap = all(len(t) <= _WHOLE_CELL or " " not in t for t in text)
    for unit, aged in rows.items():
        style = "dim" if aged.stale else ""
        table.add_row(unit, *(_cell(cells[unit].get(c, "-"), style, c) for c in columns),
                      _rate(aged), _age_cell(aged))
    return table


def corrections_cells(sample: dict) -> dict[str, str]:
    """The corrections sample's view (its age is the monitor's own column)."""
    cells = corrections_view(sample)
    cells.pop("age", None)
    return cells


def _field_rows(title: str, aged: Aged, cells: dict[str, str], per_row: int = 4):
    """A sample with many fields (the steering state) as name/value pairs, a few a line,
    in the order its view gives them (the ones that matter most first)."""
    from rich.text import Text

    style = "dim" if aged.stale else ""
    pairs = [("age", _age_cell(aged)), ("Hz", Text(_rate(aged))),
             *((name, _cell(value, style, name)) for name, value in cells.items())]
    table = _table(title, *([""] * (2 * per_row)), show_header=False)
    for i in range(0, len(pairs), per_row):
        row = [cell for name, value in pairs[i:i + per_row] for cell in (Text(name, style="bold"), value)]
        table.add_row(*row)
    return table


def render(view: View, title: str = "", width: int | None = None):
    """The view as one rich renderable, laid out for a screen `width` columns wide."""
    from rich.console import Group
    from rich.text import Text

    per_row = 4 if width is None else max(1, min(4, width // 40))
    tables = [_service_rows(view)]
    if view.gnss:
        tables.append(_sample_rows("GNSS", view.gnss, gnss_view, "unit", width))
    if view.ntrip:
        tables.append(_sample_rows("NTRIP client", {"ntrip": view.ntrip}, ntrip_view, "", width))
    if view.corrections:
        tables.append(_sample_rows("corrections", {topics.GNSS_CORRECTIONS.key(): view.corrections}, corrections_cells,
                                   "key", width))
    if view.imu:
        tables.append(_sample_rows("IMU", view.imu, imu_view, "unit"))
    if view.steering:
        tables.append(_field_rows("steering", view.steering, steering_view(view.steering.value), per_row))
    if view.estimator:
        tables.append(_sample_rows("estimator", {"state": view.estimator}, estimator_view, ""))
    if view.pilot:
        tables.append(_sample_rows("pilot", {"state": view.pilot}, pilot_view, ""))
    if view.truth:
        tables.append(_sample_rows("simulator truth", {"truth": view.truth}, truth_view, ""))
    if view.others or view.bad:
        others = _table("other keys", "key", "schema", "Hz", "age")
        for aged in view.others:
            others.add_row(aged.key, aged.schema or "-", _rate(aged), _age_cell(aged))
        for key, why in sorted(view.bad.items()):
            others.add_row(key, Text(f"undecodable: {why}"[:80], style="red"), "-", "-")
        tables.append(others)
    heading = title or f"viena monitor · car {view.car} · {view.total_rate_hz:.0f} samples/s"
    return Group(Text(heading, style="bold reverse", no_wrap=True, overflow="ellipsis"),
                 *(item for table in tables for item in (Text(""), table)))


def render_unreachable(car: str, why: str, waited_s: float, timeout_s: float):
    """The screen while the router cannot be reached: where, why, and for how long."""
    from rich.console import Group
    from rich.text import Text

    until = f"; giving up after {timeout_s:g} s" if timeout_s else ""
    return Group(Text(f"viena monitor · car {car}", style="bold reverse"), Text(""),
                 Text(why or "connecting...", style="bold red"),
                 Text(f"trying for {waited_s:.0f} s{until} (Ctrl-C quits)", style="dim"))


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
        tokens = session.liveliness().declare_subscriber(keys.alive(), self.on_token,
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
    add_timeout_flag(parser, 0.0)
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena monitor", _run, args)


class _Connecting:
    """Opens the session in a thread, so the screen can say what is wrong meanwhile."""

    def __init__(self, link: Connection, stop: threading.Event, timeout_s: float):
        self.started = time.monotonic()
        self.why = ""
        self.session = None
        self.failure: Fail | None = None
        self.done = threading.Event()
        threading.Thread(target=self._open, args=(link, stop, timeout_s), daemon=True).start()

    def _open(self, link: Connection, stop: threading.Event, timeout_s: float) -> None:
        try:
            self.session = link.open(stop, timeout_s, on_wait=self._waiting)
        except Fail as exc:
            self.failure = exc
        finally:
            self.done.set()

    def _waiting(self, why: str) -> None:
        self.why = why


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    tool_logging(args)
    if args.refresh <= 0:
        raise Fail("--refresh must be > 0", 2)
    link = Connection(args)
    model = MonitorModel(link.car, data_stale_s=args.stale)
    stop = stop_on_signals()
    connecting = _Connecting(link, stop, args.timeout)
    where = ", ".join(config_endpoints(link.conf, "connect")) or "the configured router"
    console = Console()
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    period = 1.0 / args.refresh
    feed = LiveFeed()
    declared: list = []
    try:
        with Live(console=console, auto_refresh=False, screen=console.is_terminal,
                  redirect_stderr=False) as live:
            next_frame = time.monotonic()
            while not stop.is_set():
                if not declared and connecting.done.is_set():
                    if connecting.session is None:
                        break                               # stopped, or gave up: said below
                    declared = feed.subscribe(connecting.session, model.keys)
                if declared:
                    feed.poll()
                now = time.monotonic()
                if now >= next_frame:
                    next_frame = now + period
                    if declared:
                        feed.apply(model)
                        view = model.view(now)
                        live.update(render(view, f"viena monitor · car {view.car} · {where} · "
                                                 f"{time.strftime('%H:%M:%S')} · "
                                                 f"{view.total_rate_hz:.0f} samples/s", console.width),
                                    refresh=True)
                    else:
                        live.update(render_unreachable(model.keys.car, connecting.why,
                                                       now - connecting.started, args.timeout),
                                    refresh=True)
                    if deadline is not None and now >= deadline:
                        break
                stop.wait(POLL_S)
    finally:
        interrupted = stop.is_set()                 # Ctrl-C or SIGTERM
        stop.set()                                  # a connecting thread gives up
        for entity in declared:
            try:
                entity.undeclare()
            except Exception:
                pass
        if connecting.done.wait(2.0) and connecting.session is not None:
            connecting.session.close()
    if connecting.failure is not None:
        raise connecting.failure
    if not declared and not interrupted:
        raise Fail(connecting.why or f"no session with {where} in {args.duration:g} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
