"""`viena sub KEYEXPR`: watch samples from anywhere the router is reachable.

Each sample is one line: `KEY {fields...}`, checked against its schema when the
encoding names one; `--json` prints one JSON object per line for programs.
"""
from __future__ import annotations

import argparse
import json
import queue
import sys
import time

from viena.common.errors import InputError
from viena.common.log import setup_logging
from viena.common.payload import is_json_text, to_jsonable
from viena.common.schema import schema_of, unpack
from viena.common.session import (Unreachable, add_common_arguments, load_settings_file, open_session,
                                  stop_on_signals, zenoh_config)


def decode_sample(payload: bytes, encoding: str | None) -> object:
    """A sample's value: checked by its schema if known, else plain msgpack or JSON."""
    schema = schema_of(encoding)
    if schema is not None:
        return schema.decode(payload)
    if is_json_text(payload, encoding):
        return json.loads(payload)
    return unpack(payload)


def format_line(key: str, value: object, as_json: bool, encoding: str | None = None) -> str:
    if as_json:
        return json.dumps({"key": key, "encoding": encoding, "value": to_jsonable(value)},
                          separators=(",", ":"))
    return f"{key} {json.dumps(to_jsonable(value), separators=(', ', ': '))}"


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena sub", description=__doc__)
    parser.add_argument("keyexpr", nargs="?", default=None,
                        help="key expression, e.g. 'viena/elettra/gnss/*/fix' (default viena/<car>/**)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("-n", "--count", type=int, default=0, help="exit after N samples")
    parser.add_argument("--timeout", type=float, default=0.0,
                        help="exit after this many seconds, connecting included (0 = run until Ctrl-C)")
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    setup_logging("WARNING" if args.log_level == "INFO" else args.log_level)
    from viena.common.keys import Keys
    from viena.common.session import car_name

    try:
        toml = load_settings_file(args)
        conf = zenoh_config(args, toml)
        keyexpr = args.keyexpr or Keys(car_name(args, toml)).all
    except InputError as exc:
        print(f"viena sub: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    try:
        session = open_session(conf, stop, timeout_s=args.timeout or None)
    except Unreachable as exc:
        print(f"viena sub: {exc}", file=sys.stderr)
        return 1
    if session is None:
        return 0
    lines: queue.Queue = queue.Queue()

    def on_sample(sample) -> None:      # zenoh's thread: decode and hand over, never block
        key, enc = str(sample.key_expr), str(sample.encoding)
        try:
            lines.put(format_line(key, decode_sample(sample.payload.to_bytes(), enc), args.json, enc))
        except (InputError, ValueError) as exc:
            lines.put(f"# {key}: undecodable sample: {exc}")

    sub = session.declare_subscriber(keyexpr, on_sample)
    seen, status = 0, 0
    deadline = time.monotonic() + args.timeout if args.timeout else None
    try:
        while not stop.is_set():
            try:
                line = lines.get(timeout=0.1)
            except queue.Empty:
                if deadline is not None and time.monotonic() > deadline:
                    status = 1 if args.count and seen < args.count else 0
                    break
                continue
            out = sys.stderr if line.startswith("# ") else sys.stdout
            print(line, file=out, flush=True)
            if not line.startswith("# "):
                seen += 1
                if args.count and seen >= args.count:
                    break
    except BrokenPipeError:
        pass
    finally:
        sub.undeclare()
        session.close()
    return status


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
