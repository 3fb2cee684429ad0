"""The life of every viena process: flags, settings, session, health, and a clean stop.

A service subclasses `Service`, names itself, names its settings dataclass
(common/settings.py), and fills in `start()` and `stop()`. Everything else is the same
everywhere:

- flags `--connect`, `--car`, `--config`, `--log-level`, `--version`, `--help`, `--unit`
  where a service has units (gnss, imu), plus one per setting (`--name-with-dashes`);
- settings: the dataclass's defaults, overlaid with the TOML file's `[<name>]` table, then
  its `[<name>.<unit>]` sub-table, then the flags; a bad file or setting stops the process
  at start with one line naming both;
- a liveliness token (discovery only, docs/dataflow.md#health-and-liveliness), a health sample once a second; a token
  already alive under the same name at start means the same unit runs elsewhere, and the
  process refuses to be a second one, in one line;
- SIGTERM/SIGINT: stop within 2 s, with every publisher, subscriber, queryable and the
  session closed (zenoh-python can hang at exit if any are left open).
"""
from __future__ import annotations

import argparse
import itertools
import logging
import signal
import socket
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from viena.common import clock
from viena.common.errors import ConfigError, SampleError
from viena.common.health import Health
from viena.common.keys import Keys
from viena.common.log import setup_logging
from viena.common.payload import reply_bytes
from viena.common.samples import info, topics
from viena.common.samples.topics import Topic
from viena.common.session import (
    add_common_arguments,
    car_name,
    load_settings_file,
    open_session,
    zenoh_config,
    zenoh_options,
)
from viena.common.settings import add_flags, given_flags, load, specs
from viena.common.signals import SIGNAL_CHECK_S, call_on_signals, exit_if_stuck
from viena.common.versions import versions

HEALTH_PERIOD_S = 1.0
#: how often a process says who it is again (its info; at start too): for a black box
#: that started after it, which repeats the last one at the start of every file
INFO_PERIOD_S = 10.0
#: how long the router may take to say whether our liveliness token is taken already
DUPLICATE_QUERY_S = 2.0



def query_payload(query) -> tuple[bytes, str | None]:
    """A command query's payload and its encoding (empty and None when it carries none)."""
    data = query.payload.to_bytes() if query.payload is not None else b""
    encoding = str(query.encoding) if query.encoding is not None else None
    return data, encoding


def reply_to(query, answer: dict, encoding: str | None, data: bytes, key: str | None = None) -> None:
    """Answer a command query in the encoding it was asked in (JSON for people, msgpack for
    programs), on `key` (a wildcard query is answered on the key that describes itself)."""
    import zenoh

    payload, reply_encoding = reply_bytes(answer, encoding, data)
    query.reply(key or query.key_expr, payload, encoding=zenoh.Encoding(reply_encoding))

class Publisher:
    """Publishes samples of one topic's schema on one of its keys; a sample that fails its
    check is logged and counted, never sent."""

    def __init__(self, owner: Service, topic: Topic, /, **chunks: str | None):
        import zenoh

        if topic.schema is None:
            raise ValueError(f"{topic.name} carries no schema: it is a command, not a stream")
        self.key, self.schema = owner.keys.of(topic, **chunks), topic.schema
        self._service = owner
        self._pub = owner.session.declare_publisher(
            self.key, encoding=zenoh.Encoding(self.schema.encoding), **zenoh_options(topic))

    def put(self, sample: dict) -> bool:
        try:
            payload = self.schema.encode(sample)
        except SampleError as exc:
            self._service.health.error("bad_sample")
            self._service.log.error("not published on %s: %s", self.key, exc)
            return False
        self._pub.put(payload)
        return True

    def undeclare(self) -> None:
        self._pub.undeclare()


@dataclass(frozen=True)
class NoSettings:
    """A service without settings of its own."""


class Service:
    """Base class of every viena process. See the module docstring."""

    #: the name in keys and in the TOML file: viena/<car>/<name>/...
    name = "service"
    #: the settings dataclass, declared with common/settings.py's `setting()`
    settings_class: type = NoSettings
    #: the unit a process runs when not told (--unit); None: the service has no units
    #: (one per car: sim, steering, estimator) and no --unit flag
    default_unit: str | None = None
    #: the identity it presents on a secured car when not its unit's or its name (the pilot's)
    identity: str | None = None
    description = ""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.log = logging.getLogger(f"viena.{self.name}")
        toml = load_settings_file(args)
        self.toml = toml
        self.unit = getattr(args, "unit", None) or self.default_unit
        self.keys = Keys(car_name(args, toml))
        self.settings = self.read_settings(toml, self.unit, args)
        self.zenoh_config = zenoh_config(args, toml, identity=self.identity or self.unit or self.name)
        self.health = Health(self.name, self.unit)
        self.stopping = clock.Event()
        self.session: Any = None           # the zenoh.Session (or the lockstep bus's), once serving
        self._declared: list = []
        self._token = None

    # -- for subclasses --------------------------------------------------------------------
    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Flags other than the settings' (each setting has its flag already)."""

    def start(self) -> None:
        """Open the device, declare publishers and queryables, start threads."""

    def stop(self) -> None:
        """Stop threads and close the device. Must return well within 2 s."""

    def publisher(self, topic: Topic, /, **chunks: str | None) -> Publisher:
        """A publisher on `topic`'s key (its placeholders from `chunks`), with its schema and
        its quality of service, from the table of topics."""
        pub = Publisher(self, topic, **chunks)
        self._declared.append(pub)
        return pub

    def declare_subscriber(self, key: str, callback: Any, **options):
        """`callback`: a function of the sample, or a zenoh handler (a RingChannel) that the
        caller reads from, as zenoh's own declare_subscriber takes either."""
        sub = self.session.declare_subscriber(key, callback, **options)
        self._declared.append(sub)
        return sub

    def declare_queryable(self, key: str, callback: Callable, **options):
        q = self.session.declare_queryable(key, callback, **options)
        self._declared.append(q)
        return q

    # -- the life ----------------------------------------------------------------------------
    def run(self) -> int:
        """The process's life: signals, a zenoh session, then `serve` until stopped."""
        call_on_signals(self._on_signal)
        session = open_session(self.zenoh_config, self.stopping)
        if session is None:
            return 0
        return self.serve(session)

    def serve(self, session: Any) -> int:
        """Run on an open session until `stopping` is set, then close everything, the
        session too. The lockstep runner (viena.common.lockstep) calls this with its
        in-memory bus's session, on its virtual clock: the rest is the car's code path."""
        self.session = session
        other = self.running_elsewhere()
        if other is not None:
            print(f"viena-{self.name}: {other}", file=sys.stderr, flush=True)
            self.session.close()
            return 2
        self.log.info("started: car %s, unit %s, zenoh id %s", self.keys.car, self.unit,
                      self.session.zid())
        try:
            self._token = self.session.liveliness().declare_token(self.keys.alive(self.name, self.unit))
            health_pub = self.publisher(topics.HEALTH, service=self.name, unit=self.unit)
            put_info = self._info_sampler()
            self.start()
            next_info = clock.monotonic()
            for _ in self._health_periods():
                health_pub.put(self.health.snapshot())
                if clock.monotonic() >= next_info:
                    put_info()
                    next_info = clock.monotonic() + INFO_PERIOD_S
        finally:
            self._shutdown()
        return 0

    def _health_periods(self) -> Iterator[None]:
        """Once every HEALTH_PERIOD_S until stopping. On the wall clock the main thread
        wakes every SIGNAL_CHECK_S meanwhile: a SIGTERM the kernel gave one of zenoh's
        threads waits for the main thread to run its handler (common/signals.py), and the
        stop deadline starts only then. On a virtual clock nothing signals."""
        step = HEALTH_PERIOD_S if clock.is_virtual() else SIGNAL_CHECK_S
        due = clock.monotonic() + HEALTH_PERIOD_S
        while not self.stopping.wait(min(step, max(due - clock.monotonic(), 0.0))):
            if clock.monotonic() >= due:
                due += HEALTH_PERIOD_S
                if due <= clock.monotonic():             # held up a whole period: no burst after it
                    due = clock.monotonic() + HEALTH_PERIOD_S
                yield

    def _info_sampler(self) -> Callable[[], None]:
        """Puts this process's info (common/samples/info.py), now and each time it is called."""
        pub = self.publisher(topics.INFO, service=self.name, unit=self.unit)
        fixed = {"service": self.name, "unit": self.unit, "started": clock.time_ns(), "host": socket.gethostname(),
                 "versions": versions(), "settings": info.settings_map(self.settings)}
        seq = itertools.count()

        def put() -> None:
            pub.put({"t": clock.time_ns(), "seq": next(seq), **fixed})
        put()
        return put

    def running_elsewhere(self) -> str | None:
        """Why this process must not run, if the same unit already runs on this car (its
        liveliness token is alive): two gnss0 would publish one key from two receivers."""
        key = self.keys.alive(self.name, self.unit)
        replies = self.session.liveliness().get(key, timeout=DUPLICATE_QUERY_S)
        if not any(reply.ok is not None for reply in replies):
            return None
        who = self.unit or self.name
        fix = ", or give this one another --unit" if self.default_unit is not None else ""
        return (f"{who} already runs on car {self.keys.car} ({key} is alive): stop that one "
                f"first{fix}")

    def _on_signal(self, signum: int) -> None:
        """SIGTERM or SIGINT, on a thread of its own (viena.common.signals says why)."""
        if self.stopping.is_set():
            return
        self.log.info("%s: stopping", signal.Signals(signum).name)
        self.stopping.set()
        exit_if_stuck(self.log)

    def _shutdown(self) -> None:
        self.stopping.set()
        try:
            self.stop()
        except Exception:
            self.log.exception("error while stopping")
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception as exc:
                self.log.debug("undeclare failed: %s", exc)
        self._declared.clear()
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
        if self.session is not None:
            self.session.close()
        self.log.info("stopped")

    # -- settings ------------------------------------------------------------------------------
    @classmethod
    def read_settings(cls, toml: dict, unit: str | None, args: argparse.Namespace) -> Any:
        """Defaults < [<name>] < [<name>.<unit>] < flags. A sub-table that is not a
        setting is a unit's (or, in [sim], a device's)."""
        source = str(getattr(args, "config", None))
        table = toml.get(cls.name, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: [{cls.name}] must be a table")
        known = specs(cls.settings_class)
        units = {k: v for k, v in table.items() if isinstance(v, dict) and k not in known}
        layers = [({k: v for k, v in table.items() if k not in units}, f"{source} [{cls.name}]")]
        if unit and unit in units:
            layers.append((units[unit], f"{source} [{cls.name}.{unit}]"))
        layers.append((given_flags(args, cls.settings_class), "command line"))
        return load(cls.settings_class, layers)


def build_parser(cls: type[Service]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=f"viena-{cls.name}", description=cls.description or (cls.__doc__ or "").strip(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_arguments(parser)
    if cls.default_unit is not None:
        parser.add_argument("--unit", metavar="NAME", default=None,
                            help=f"which unit this process runs (default {cls.default_unit}); "
                                 f"its settings come from the [{cls.name}.NAME] table")
    add_flags(parser, cls.settings_class, f"settings (the [{cls.name}] table of --config; a flag wins)")
    cls.add_arguments(parser)
    return parser


def run_service(cls: type[Service], argv: list[str] | None = None) -> int:
    """Console-script entry point: parse, configure, run; input errors are one line."""
    args = build_parser(cls).parse_args(argv)
    setup_logging(args.log_level)
    try:
        service = cls(args)
    except ConfigError as exc:
        print(f"viena-{cls.name}: config error: {exc}", file=sys.stderr)
        return 2
    try:
        return service.run()
    except ConfigError as exc:
        logging.getLogger(f"viena.{cls.name}").error("config error: %s", exc)
        return 2
