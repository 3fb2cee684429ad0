"""`viena sub KEYEXPR`: watch samples from anywhere the router is reachable.

Each sample is one line: `KEY {fields...}`, checked against its schema when the
encoding names one; `--json` prints one JSON object per line for programs.
`--field accel_mps2` prints only that field (a dotted path reaches inside: `decision.reason`,
`accel_mps2.2`); several --field print a map of them. Nothing on the key for a few
seconds is said on stderr (a misspelt key is otherwise silence).
"""
from __future__ import annotations

import argparse
import json
import queue
import sys
import time

from viena.common.errors import InputError
from viena.common.payload import is_json_text, to_jsonable
from viena.common.schema import schema_of, unpack
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import CONNECT_TIMEOUT_S, Connection, SilenceWarning, guarded, key_expressions, tool_logging

MISSING = object()


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


def field(value: object, path: str) -> object:
    """`value` at a dotted path ('accel_mps2', 'decision.reason', 'enu_m.0'), else MISSING."""
    for part in path.split("."):
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, (list, tuple)) and part.lstrip("-").isdigit() and -len(value) <= int(part) < len(value):
            value = value[int(part)]
        else:
            return MISSING
    return value


def select(value: object, paths: list[str]) -> tuple[object, list[str]]:
    """The fields `paths` of a sample (the value itself for one path); and those missing."""
    found = {p: field(value, p) for p in paths}
    missing = [p for p, v in found.items() if v is MISSING]
    if len(paths) == 1:
        return found[paths[0]], missing
    return {p: v for p, v in found.items() if v is not MISSING}, missing


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena sub", description=__doc__)
    parser.add_argument("keyexpr", nargs="?", default=None,
                        help="key expression, e.g. 'viena/elettra/gnss/*/fix' (default viena/<car>/**)")
    parser.add_argument("--field", action="append", metavar="NAME",
                        help="print only this field (dotted path: decision.reason, enu_m.0); repeatable")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("-n", "--count", type=int, default=0, help="exit after N samples")
    parser.add_argument("--timeout", type=float, default=0.0, metavar="S",
                        help="exit after this many seconds, connecting included: a router not reached "
                             f"by then is an error (default 0: run until Ctrl-C, having given up "
                             f"if the router cannot be reached in {CONNECT_TIMEOUT_S:g} s)")
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena sub", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    link = Connection(args)
    [keyexpr] = key_expressions([args.keyexpr or link.keys.all])
    stop = stop_on_signals()
    session = link.open(stop, args.timeout or CONNECT_TIMEOUT_S)
    if session is None:
        return 0
    lines: queue.Queue = queue.Queue()
    silence = SilenceWarning("viena sub", [keyexpr])
    told_missing: set[tuple[str, str]] = set()

    def on_sample(sample) -> None:      # zenoh's thread: decode and hand over, never block
        silence.heard()
        key, enc = str(sample.key_expr), str(sample.encoding)
        try:
            value = decode_sample(sample.payload.to_bytes(), enc)
        except (InputError, ValueError) as exc:
            lines.put(f"# {key}: undecodable sample: {exc}")
            return
        if args.field:
            whole = value
            value, missing = select(whole, args.field)
            for path in missing:
                if (key, path) not in told_missing:
                    told_missing.add((key, path))
                    have = ", ".join(map(str, whole)) if isinstance(whole, dict) else ""
                    lines.put(f"# {key}: no field '{path}'" + (f" (it has: {have})" if have else ""))
            if missing and len(args.field) == 1:
                return
        lines.put(format_line(key, value, args.json, enc))

    sub = session.declare_subscriber(keyexpr, on_sample)
    seen, status = 0, 0
    deadline = time.monotonic() + args.timeout if args.timeout else None
    try:
        while not stop.is_set():
            silence.check()
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


if __name__ == "__main__":
    sys.exit(main())
