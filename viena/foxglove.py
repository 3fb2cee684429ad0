"""`viena foxglove [--port 8765]`: the car, live, in Foxglove or Lichtblick.

Subscribes to the car (`viena/<car>/**`, the same connection flags and identities as the
other laptop tools) and serves it with the Foxglove SDK's WebSocket server: open
`ws://HOST:PORT` in Foxglove ("Open connection" > "Foxglove WebSocket"). Every key is a
JSON channel whose JSON Schema comes from viena's own schema, so any numeric field can be
plotted; GNSS receivers, the estimator and the simulated truth are also
`foxglove.LocationFix` (Map panel), `PoseInFrame` and `FrameTransform` (3D panel, frames
`enu` -> `car`, `car_truth`), each receiver's solution type and correction age and the
NTRIP client's link are JSON status channels, services' health errors become `foxglove.Log`, and the
route the pilot holds (pilot/path) is `foxglove.GeoJSON` (Map panel) and a SceneUpdate
line in `enu` (3D panel) (viena/foxglove_messages.py has the table).

The one thing a client may send is the emergency stop: a service `estop` (Foxglove's
Service Call panel) that puts on `viena/<car>/steering/estop`, offered only when this
tool's identity may (the `observer` and `pilot` roles), and never with `--no-estop`.

A browser never slows the car: zenoh's threads only put each sample in a ring
(zenoh.handlers.RingChannel, no Python on zenoh's threads: when full, the oldest samples
are dropped); one thread takes them from it, converts and hands them to the server,
which keeps at most `--backlog` messages per client and drops the oldest for a client
that does not keep up. Nobody subscribed to a key: its samples are not even decoded.
`--max-rate HZ` keeps at most HZ samples a second per key for slow links.
Ctrl-C or SIGTERM stop it within a second.

The server speaks the Foxglove WebSocket protocol under its current name,
`foxglove.sdk.v1` (the same protocol as `foxglove.websocket.v1`): current Foxglove, and
Lichtblick since it accepts that name, connect.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
import time

from viena.common.access import ROLES
from viena.common.keys import Keys
from viena.common.log import setup_logging
from viena.common.recorder import RingSubscribers
from viena.common.samples import topics
from viena.common.session import PERSON_IDENTITY, add_common_arguments, config_endpoints, zenoh_options
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, SilenceWarning, add_timeout_flag, guarded, key_expressions

log = logging.getLogger("viena.foxglove")
DEFAULT_PORT = 8765
#: messages kept per client by the server; the oldest is dropped when a client lags
DEFAULT_BACKLOG = 256
#: the ring's size: samples waiting for the converting thread (about 2 s of the car)
QUEUE_SAMPLES = 1000
#: the converting thread takes what came this often (Bridge)
BATCH_S = 0.025
ESTOP_SERVICE = "estop"
ESTOP_KEY = topics.STEERING_ESTOP.key()
REPORT_PERIOD_S = 10.0


class Downsampler:
    """At most `rate_hz` samples a second per key (0: all): the first sample of each period
    passes. Periods follow a steady schedule, so the rate holds on average; after a silence
    the schedule starts again, so a pause is never followed by a burst."""

    def __init__(self, rate_hz: float):
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self._next: dict[str, float] = {}

    def keep(self, key: str, now_s: float) -> bool:
        if not self.period_s:
            return True
        due = self._next.get(key, 0.0)
        if now_s < due:
            return False
        on_schedule = now_s - due < self.period_s
        self._next[key] = (due if on_schedule else now_s) + self.period_s
        return True


class Bridge:
    """zenoh samples -> Foxglove channels. `start()` subscribes and starts the converting
    thread; `stop()` undeclares (what is still in the ring is dropped) and stops the thread.

    The samples wait in zenoh's own ring (in Rust) for the one converting thread, which
    takes all that came every BATCH_S (common/recorder.py RingSubscribers, as the black box
    does): some 40 wake-ups a second rather than one per sample (330 a second with one
    client on the car's every key), or two for a Python callback (zenoh runs it on a Python
    thread of its own). A viewer sees a sample at most BATCH_S later; Foxglove draws some
    60 frames a second. Each sample's log time is still its arrival, at the car's router
    (its zenoh timestamp), and `--max-rate` thins by that time."""

    def __init__(self, session, keyexpr: str, channels, max_rate_hz: float = 0.0):
        self.session, self.keyexpr, self.channels = session, keyexpr, channels
        self.downsampler = Downsampler(max_rate_hz)
        self.rings = RingSubscribers(samples=QUEUE_SAMPLES)
        self.silence = SilenceWarning("viena foxglove", [keyexpr])
        #: batches in which the ring was full: zenoh may have dropped its oldest samples
        self.possibly_dropped = 0
        self._subscriber = None
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stopping.clear()
        (subscriber,) = self.rings.declare(self.session, [self.keyexpr])
        self._subscriber = subscriber
        # the handler, not the subscriber: undeclaring the subscriber while this thread reads
        # it could fail ("Already borrowed"); its handler's try_recv() raises instead
        self._thread = threading.Thread(target=self._convert_loop, args=(subscriber.handler,),
                                        name="foxglove-convert", daemon=True)
        self._thread.start()

    def _convert_loop(self, handler) -> None:
        while not self._stopping.wait(BATCH_S):
            taken, counts = self.rings.take([handler], self.channels.wanted)   # nobody watches it: not even copied
            if self._stopping.is_set():
                return
            if counts[0] >= self.rings.samples:
                self.possibly_dropped += 1       # said in the bridge's report, every REPORT_PERIOD_S at most
            if taken:
                self.silence.heard()
            self._convert(taken)

    def _convert(self, taken: list[tuple[int, str, str, bytes]]) -> None:
        publish, thin = self.channels.publish, self.downsampler
        for log_time, key, encoding, data in taken:
            if thin.period_s and not thin.keep(key, log_time / 1e9):
                continue
            try:
                publish(key, encoding, data, log_time)
            except Exception:           # a bug in one conversion must not end the bridge
                log.exception("cannot convert a sample on %s", key)

    def stop(self) -> None:
        self._stopping.set()                                      # first: the thread's end is then no news
        subscriber, self._subscriber = self._subscriber, None
        if subscriber is not None:
            try:
                subscriber.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        if self._thread is not None:
            self._thread.join(timeout=2.0)


def estop_allowed(args: argparse.Namespace, link: Connection) -> tuple[bool, str]:
    """May this tool put the e-stop? On a secured link only if its identity's role says so
    (the router would refuse it anyway); on an open link anyone may."""
    from viena.common.keystore import KeyStore
    from viena.common.secure import is_secure

    if getattr(args, "no_estop", False):
        return False, "--no-estop"
    if not any(is_secure(e) for e in config_endpoints(link.conf, "connect")):
        return True, "open link: no access control"
    name = args.identity or os.environ.get("VIENA_IDENTITY") or PERSON_IDENTITY
    try:
        role = KeyStore.for_car(link.car, args.keys).identity(name).role
    except Exception as exc:
        return False, f"identity {name!r}: {exc}"
    allowed = role in ROLES and ESTOP_KEY in ROLES[role].publish
    return allowed, f"identity {name!r}, role {role!r}"


def estop_service(session, keys: Keys):
    """The Foxglove service `estop`: a put on steering/estop, answered {"status": "sent"}."""
    import foxglove

    key = keys.of(topics.STEERING_ESTOP)
    request = {"type": "object", "title": "viena.estop.request",
               "properties": {"reason": {"type": "string"}}, "additionalProperties": True}
    response = {"type": "object", "title": "viena.estop.response",
                "properties": {"status": {"type": "string"}, "key": {"type": "string"}},
                "required": ["status", "key"]}

    def schema(s: dict) -> foxglove.MessageSchema:
        return foxglove.MessageSchema(encoding="json", schema=foxglove.Schema(
            name=s["title"], encoding="jsonschema", data=json.dumps(s).encode()))

    def handle(req) -> bytes:
        reason = ""
        try:
            body = json.loads(req.payload or b"{}")
            reason = str(body.get("reason", "")) if isinstance(body, dict) else ""
        except ValueError:
            pass
        log.warning("e-stop from Foxglove client %s%s", req.client_id, f": {reason}" if reason else "")
        session.put(key, json.dumps({"by": "viena foxglove", "client": req.client_id, "reason": reason}),
                    encoding="application/json", **zenoh_options(topics.STEERING_ESTOP))
        return json.dumps({"status": "sent", "key": key}).encode()

    return foxglove.Service(ESTOP_SERVICE, schema=foxglove.ServiceSchema(
        "viena.estop", request=schema(request), response=schema(response)), handler=handle)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena foxglove", description=__doc__,
                                               formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("keyexpr", nargs="?", default=None,
                        help="what to serve (default viena/<car>/**)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help=f"WebSocket port (default {DEFAULT_PORT}; 0 picks a free one)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default 127.0.0.1; 0.0.0.0 for other machines)")
    parser.add_argument("--max-rate", type=float, default=0.0, metavar="HZ",
                        help="at most HZ samples a second per key, for slow links (default 0: all)")
    parser.add_argument("--backlog", type=int, default=DEFAULT_BACKLOG, metavar="N",
                        help=f"messages kept per client; a client that lags loses the oldest "
                             f"(default {DEFAULT_BACKLOG})")
    parser.add_argument("--no-estop", action="store_true", help="offer no e-stop service")
    add_timeout_flag(parser)
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena foxglove", _run, args)


def _run(args: argparse.Namespace) -> int:
    import foxglove
    from foxglove.websocket import Capability

    from viena.foxglove_channels import FoxgloveChannels

    setup_logging(args.log_level)
    if args.backlog < 1 or args.max_rate < 0 or not 0 <= args.port < 65536:
        raise Fail("--backlog must be >= 1, --max-rate >= 0 and --port within 0..65535", 2)
    link = Connection(args)
    [keyexpr] = key_expressions([args.keyexpr or link.keys.all])
    may_estop, why = estop_allowed(args, link)
    stop = stop_on_signals()
    session = link.open(stop, args.timeout)
    if session is None:
        return 0
    context = foxglove.Context()
    services = [estop_service(session, link.keys)] if may_estop else []
    try:
        server = foxglove.start_server(
            name=f"viena {link.car}", host=args.host, port=args.port, context=context,
            capabilities=[Capability.Services] if services else [], services=services or None,
            supported_encodings=["json"], message_backlog_size=args.backlog)
    except Exception as exc:
        session.close()
        raise Fail(f"cannot serve on {args.host}:{args.port}: {exc}") from None
    channels = FoxgloveChannels(context)
    bridge = Bridge(session, keyexpr, channels, args.max_rate)
    bridge.start()
    print(f"viena foxglove: serving {keyexpr} on ws://{args.host}:{server.port} "
          f"(e-stop {'offered' if services else 'not offered'}: {why})", file=sys.stderr, flush=True)
    reported = full = 0
    next_report = time.monotonic() + REPORT_PERIOD_S
    try:
        while not stop.wait(0.2):
            bridge.silence.check()
            if time.monotonic() >= next_report:
                next_report = time.monotonic() + REPORT_PERIOD_S
                invalid = sum(channels.invalid.values())
                if invalid > reported:
                    log.warning("%d samples failed their schema", invalid)
                    reported = invalid
                if bridge.possibly_dropped > full:
                    log.warning("the bridge fell behind the car %d times: zenoh's ring (%d samples) may have "
                                "dropped the oldest", bridge.possibly_dropped, QUEUE_SAMPLES)
                    full = bridge.possibly_dropped
    finally:
        bridge.stop()
        server.stop()
        channels.close()
        session.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
