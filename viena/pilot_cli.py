"""`viena route` and `viena pilot`: give the pilot a route, start and stop it, watch it.

    viena route send FILE                 a route to follow (GeoJSON, point list, Titans
                                          checkpoints, CSV lat,lon[,speed]); prints the
                                          parsed route, or the one reason it was refused
    viena route show [-o FILE]            the route the pilot holds, as GeoJSON
    viena route record -o route.geojson   record a route by driving: a point every
                         [--every-m 2]    --every-m metres of the estimate (Ctrl-C ends it)
    viena pilot start | stop              the Titans' start/stop
    viena pilot status [--json]           one pilot/state sample

Commands (route send and show, pilot start and stop) go as the `pilot` identity on a
secured car ($VIENA_IDENTITY or --identity for another person's); status and record watch
as `observer`. Standalone: `python -m viena.pilot_cli`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import queue
import sys
import time
from pathlib import Path

from viena.common.errors import InputError
from viena.common.payload import is_json_text, to_jsonable
from viena.common.samples import topics
from viena.common.schema import unpack
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, add_timeout_flag, guarded, tool_logging

ROUTE_HELP = "give the pilot a route, show it, or record one by driving"
PILOT_HELP = "start or stop the pilot, or show its state"


def add_commands(cmds) -> None:
    """`viena route ...` and `viena pilot ...` on the `viena` command's subparsers."""
    for name, help_text, build, run in (("route", ROUTE_HELP, build_route_parser, run_route),
                                        ("pilot", PILOT_HELP, build_pilot_parser, run_pilot)):
        p = cmds.add_parser(name, help=help_text, description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        build(p)
        p.set_defaults(func=run)


def _common(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p)
    add_timeout_flag(p)


def build_route_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena route", description=__doc__)
    sub = parser.add_subparsers(dest="route_command", required=True, metavar="COMMAND")
    p = sub.add_parser("send", help="send a route file to the pilot")
    p.add_argument("file", help="the route ('-': standard input)")
    _common(p)
    p = sub.add_parser("show", help="print the pilot's route as GeoJSON")
    p.add_argument("-o", "--output", metavar="FILE", help="write it here instead")
    _common(p)
    p = sub.add_parser("record", help="record a route by driving (Ctrl-C ends it)")
    p.add_argument("-o", "--output", metavar="FILE", required=True, help="the GeoJSON file to write")
    p.add_argument("--every-m", type=float, default=2.0, help="a point every this many metres (default 2)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after this long (default: Ctrl-C)")
    p.add_argument("--max-sigma-m", type=float, default=0.5,
                   help="skip estimates less certain than this, horizontally (default 0.5)")
    _common(p)
    return parser


def build_pilot_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena pilot", description=__doc__)
    sub = parser.add_subparsers(dest="pilot_command", required=True, metavar="COMMAND")
    for name, help_text in (("start", "start following the route"), ("stop", "stop steering and disarm")):
        _common(sub.add_parser(name, help=help_text))
    p = sub.add_parser("status", help="the pilot's state")
    p.add_argument("--json", action="store_true", help="the whole sample as JSON")
    _common(p)
    return parser


def run_route(args: argparse.Namespace) -> int:
    return guarded("viena route", _route, args)


def run_pilot(args: argparse.Namespace) -> int:
    return guarded("viena pilot", _pilot, args)


# -- the commands -------------------------------------------------------------------------------
def _connect(args, command: bool):
    tool_logging(args)
    identity = (os.environ.get("VIENA_IDENTITY") or "pilot") if command else None
    link = Connection(args, identity=identity)
    session = link.open(stop_on_signals(), args.timeout)
    if session is None:
        raise Fail("interrupted", 1)
    return link, session


def _ask(session, key: str, payload: bytes | None, timeout_s: float) -> dict:
    replies = [r.ok for r in session.get(key, payload=payload, timeout=timeout_s) if r.ok is not None]
    if not replies:
        raise Fail(f"no answer on {key}: is viena-pilot running?", 1)
    return _decoded(replies[0].payload.to_bytes(), key)


def _decoded(data: bytes, what: str) -> dict:
    """An answer in JSON text or msgpack (the pilot answers in the question's encoding,
    msgpack to a question without payload)."""
    try:
        return json.loads(data) if is_json_text(data) else unpack(data, what)
    except (ValueError, InputError) as exc:
        raise Fail(f"unreadable answer on {what}: {exc}", 1) from None


def _route(args) -> int:
    if args.route_command == "send":
        from viena.services.pilot.model.route import MAX_ROUTE_BYTES

        data = sys.stdin.buffer.read() if args.file == "-" else _read(args.file)
        if len(data) > MAX_ROUTE_BYTES:           # the pilot would refuse it, the router might drop it
            raise Fail(f"route refused: {len(data)} bytes: at most {MAX_ROUTE_BYTES} are read", 1)
    link, session = _connect(args, command=args.route_command in ("send", "show"))
    key = link.keys.of(topics.PILOT_ROUTE)
    try:
        if args.route_command == "record":
            return _record(session, link, args)
        if args.route_command == "send":
            answer = _ask(session, key, data, max(args.timeout, 5.0))
            if answer.get("status") != "accepted":
                raise Fail(f"route refused: {answer.get('reason')}", 1)
            props = answer["route"]["properties"]
            print(f"route accepted: {props['points']} checkpoints, {props['length_m']:.0f} m "
                  f"({props['form']}); pilot {answer.get('mode')}")
            return 0
        answer = _ask(session, key, None, max(args.timeout, 5.0))
        if answer.get("status") != "accepted":
            raise Fail(str(answer.get("reason")), 1)
        text = json.dumps(answer["route"], indent=1)
        if args.output:
            Path(args.output).write_text(text + "\n")
        else:
            print(text)
        return 0
    finally:
        session.close()


def _read(path: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise Fail(f"cannot read {path}: {exc.strerror}", 2) from None


def _pilot(args) -> int:
    link, session = _connect(args, command=args.pilot_command != "status")
    try:
        if args.pilot_command == "status":
            state = _one_state(session, link.keys.of(topics.PILOT_STATE), max(args.timeout, 3.0))
            if args.json:
                print(json.dumps(to_jsonable(state)))
            else:
                from viena.common.samples.pilot import monitor_view
                for name, value in monitor_view(state).items():
                    print(f"{name:12s} {value}")
            return 0
        answer = _ask(session, link.keys.of(topics.PILOT_CMD), json.dumps({"cmd": args.pilot_command}).encode(),
                      max(args.timeout, 5.0))
        if answer.get("status") != "accepted":
            raise Fail(f"{args.pilot_command} refused: {answer.get('reason')}", 1)
        print(f"pilot {answer.get('mode')}")
        return 0
    finally:
        session.close()


def _one_state(session, key: str, timeout_s: float) -> dict:
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(key, lambda s: got.put(s.payload.to_bytes()))
    try:
        raw = got.get(timeout=timeout_s)
    except queue.Empty:
        raise Fail(f"no state on {key} in {timeout_s:g} s: is viena-pilot running?", 1) from None
    finally:
        sub.undeclare()
    return _decoded(raw, key)


def _record(session, link, args) -> int:
    """A point every --every-m metres of valid estimate, written as a GeoJSON Feature."""
    from viena.services.pilot.model.estimate import estimate_of
    from viena.services.pilot.model.route import MIN_SPACING_M, checked

    if not args.every_m >= MIN_SPACING_M:
        raise Fail(f"--every-m must be at least {MIN_SPACING_M} m", 2)
    estimates: queue.Queue = queue.Queue(maxsize=1000)
    key = link.keys.of(topics.ESTIMATOR_STATE)

    def keep(sample) -> None:          # the newest are dropped while the queue is full
        if not estimates.full():
            estimates.put(sample.payload.to_bytes())

    sub = session.declare_subscriber(key, keep)
    stop = stop_on_signals()
    points: list[tuple[float, float]] = []
    last_enu = None
    end = time.monotonic() + args.seconds if args.seconds else None
    print(f"recording a point every {args.every_m:g} m to {args.output}; Ctrl-C ends it", file=sys.stderr)
    try:
        while not stop.is_set() and (end is None or time.monotonic() < end):
            try:
                est = estimate_of(unpack(estimates.get(timeout=0.2), "estimator state"))
            except (queue.Empty, InputError):         # nothing yet, or a state the schema refuses
                continue
            if (not est.position_valid or est.lat_deg is None or est.lon_deg is None
                    or est.sigma_h_m > args.max_sigma_m):
                continue
            enu, latlon = (est.x_m, est.y_m), (est.lat_deg, est.lon_deg)
            if last_enu is None or math.dist(enu, last_enu) >= args.every_m:
                points.append(latlon)
                last_enu = enu
                print(f"  {len(points)}: {latlon[0]:.7f}, {latlon[1]:.7f}", file=sys.stderr)
    finally:
        sub.undeclare()
    if len(points) < 2:
        raise Fail(f"recorded {len(points)} point(s): drive at least {args.every_m:g} m with a valid estimate", 1)
    try:
        route = checked(points, [None] * len(points), "geojson")
    except ValueError as exc:
        raise Fail(f"the recording is not a route: {exc}", 1) from None
    Path(args.output).write_text(json.dumps(route.to_geojson(), indent=1) + "\n")
    print(f"{len(route)} points, {route.length_m:.0f} m written to {args.output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m viena.pilot_cli", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_commands(parser.add_subparsers(dest="command", required=True, metavar="COMMAND"))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
