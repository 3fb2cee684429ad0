"""`viena list`: the keys the car publishes, each with its schema and rate (beside the
rate the table of topics, common/samples/topics.py, gives the simulated car, and the
program that publishes it), and the processes that are alive (their liveliness tokens).

It listens to viena/<car>/** (or KEYEXPR) for --duration seconds, so a key is listed once
a sample has come on it: keys slower than that (none of viena's, whose slowest is
health at 1 Hz) may be missed. Queries and commands (steering/arm, ...) carry no samples
and are not listed; `viena keys roles` says who may use them.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from viena.common.recording import schema_name
from viena.common.samples.topics import topic_of_key
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.hz import RateMeter
from viena.tool import Connection, Fail, add_timeout_flag, guarded, key_expressions, tool_logging

DURATION_S = 2.5


class KeyTable:
    """What came on each key while listening: its encoding and a RateMeter."""

    def __init__(self):
        self._lock = threading.Lock()
        self.keys: dict[str, tuple[str, RateMeter]] = {}

    def add(self, key: str, encoding: str, t_s: float, n_bytes: int) -> None:
        with self._lock:
            entry = self.keys.get(key)
            if entry is None:
                entry = self.keys[key] = (encoding, RateMeter(window=100_000))
            entry[1].add(t_s, n_bytes)

    def rows(self) -> list[dict]:
        with self._lock:
            items = sorted(self.keys.items())
        rows = []
        for key, (encoding, meter) in items:
            rates = meter.rates()
            found = topic_of_key(key)
            topic = None if found is None else found[0]
            rows.append({"key": key, "schema": schema_name(encoding) or encoding or "-",
                         "rate_hz": rates.rate_hz, "samples": rates.samples,
                         "bytes_per_sample": rates.bytes_per_sample,
                         "topic": None if topic is None else topic.name,
                         "nominal_hz": None if topic is None else topic.nominal_hz,
                         "producer": None if topic is None else topic.producer})
        return rows


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena list", description=__doc__)
    parser.add_argument("keyexpr", nargs="?", default=None, metavar="KEYEXPR",
                        help="list only the keys this includes (default viena/<car>/**)")
    parser.add_argument("--duration", type=float, default=DURATION_S, metavar="S",
                        help=f"listen this long (default {DURATION_S:g} s)")
    parser.add_argument("--json", action="store_true", help="one JSON object per key")
    add_timeout_flag(parser)
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena list", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    if args.duration <= 0:
        raise Fail("--duration must be > 0", 2)
    link = Connection(args)
    [keyexpr] = key_expressions([args.keyexpr or link.keys.all])
    stop = stop_on_signals()
    session = link.open(stop, args.timeout)
    if session is None:
        return 0
    table = KeyTable()
    sub = session.declare_subscriber(keyexpr, lambda s: table.add(
        str(s.key_expr), str(s.encoding), time.monotonic(), len(s.payload)))
    try:
        stop.wait(args.duration)
        alive = sorted(str(r.ok.key_expr).removeprefix(link.keys.alive()[:-2])
                       for r in session.liveliness().get(link.keys.alive(), timeout=2.0)
                       if r.ok is not None)
    finally:
        sub.undeclare()
        session.close()
    rows = table.rows()
    if args.json:
        for row in rows:
            print(json.dumps(row))
    else:
        _print(rows, alive, args.duration)
    if not rows:
        raise Fail(f"nothing on '{keyexpr}' in {args.duration:g} s"
                   + ("" if alive else ": no process of this car is alive either"))
    return 0


def _print(rows: list[dict], alive: list[str], duration_s: float) -> None:
    width = max([len("KEY"), *(len(r["key"]) for r in rows)])
    schema_width = max([len("SCHEMA"), *(len(r["schema"]) for r in rows)])
    print(f"{'KEY':<{width}}  {'SCHEMA':<{schema_width}}  {'RATE Hz':>8}  {'NOMINAL':>8}  {'B/SAMPLE':>8}  PRODUCER")
    for r in rows:
        rate = f"{r['rate_hz']:.1f}" if r["rate_hz"] is not None else f"<{1 / duration_s:.1f}"
        nominal = "-" if r["nominal_hz"] is None else f"{r['nominal_hz']:g}"
        print(f"{r['key']:<{width}}  {r['schema']:<{schema_width}}  {rate:>8}  {nominal:>8}  "
              f"{r['bytes_per_sample']:>8.0f}  {r['producer'] or '-'}")
    print(f"alive: {', '.join(alive) if alive else 'no process (no liveliness token)'}")


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
