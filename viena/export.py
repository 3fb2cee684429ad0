"""`viena export drive.mcap --csv DIR` (or `--json [FILE]`): a recording for spreadsheets and scripts.
`--format foxglove -o drive-fox.mcap`: a recording Foxglove opens (viena/foxglove_export.py).

--csv writes one file per key into DIR (viena.elettra.gnss.gnss0.fix.csv), one row per
sample: log_time_ns, publish_time_ns, then the sample's fields, nested ones flattened
with dots (ecef_m.0, ecef_m.1, raw.accel_g.2, rates_hz.truth). A field a sample lacks is
an empty cell. --json writes JSON lines {key, schema, log_time_ns, publish_time_ns, value}
to FILE (default stdout). Like replay, export reads a damaged recording as far as it can
and says where it stopped. A drive of the black box (its directory or its id) is exported
as one recording, each sample once; one of its files alone is exported alone.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from viena.common.errors import InputError, SampleError
from viena.common.payload import to_jsonable
from viena.common.recording import KeyFilter, Source, open_source
from viena.tool import add_drive_arguments

TIME_COLUMNS = ["log_time_ns", "publish_time_ns"]


def flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(column, cell) pairs: maps and lists flattened with dots, None as an empty cell."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from flatten(v, f"{prefix}.{i}" if prefix else str(i))
    else:
        yield prefix or "value", _cell(value)


def _cell(v: Any) -> Any:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, (bytes, bytearray)):
        return bytes(v).hex()
    if isinstance(v, float):
        return repr(v)                   # every digit: float64 ECEF keeps its millimetres
    return v


def csv_name(key: str) -> str:
    return key.replace("/", ".") + ".csv"


class Undecodable:
    """Counts samples that are neither msgpack nor JSON, per key, to report once."""

    def __init__(self):
        self.by_key: dict[str, int] = {}

    def add(self, key: str) -> None:
        self.by_key[key] = self.by_key.get(key, 0) + 1

    def report(self) -> list[str]:
        return [f"{n} undecodable samples on {key} skipped" for key, n in sorted(self.by_key.items())]


def _rows(recording: Source, keys: KeyFilter, bad: Undecodable):
    for msg in recording.messages(keys):
        try:
            value = msg.value()
        except SampleError:
            bad.add(msg.key)
            continue
        yield msg, value


def export_csv(recording: Source, directory: Path, keys: KeyFilter) -> dict[str, int]:
    """Two passes: the first learns each key's columns (fields appear and disappear as
    producers change), the second writes. Returns rows written per key."""
    columns: dict[str, dict[str, None]] = {}
    for msg, value in _rows(recording, keys, Undecodable()):
        cols = columns.setdefault(msg.key, dict.fromkeys(TIME_COLUMNS))
        for name, _ in flatten(value):
            cols.setdefault(name, None)
    directory.mkdir(parents=True, exist_ok=True)
    files, writers, counts = {}, {}, {}
    bad = Undecodable()
    try:
        for key, cols in columns.items():
            f = files[key] = open(directory / csv_name(key), "w", newline="")
            writers[key] = csv.DictWriter(f, fieldnames=list(cols), restval="")
            writers[key].writeheader()
            counts[key] = 0
        for msg, value in _rows(recording, keys, bad):
            row = dict(flatten(value))
            row["log_time_ns"], row["publish_time_ns"] = msg.log_time, msg.publish_time
            writers[msg.key].writerow(row)
            counts[msg.key] += 1
    finally:
        for f in files.values():
            f.close()
    recording.problems.extend(bad.report())
    return counts


def export_json(recording: Source, out, keys: KeyFilter) -> int:
    bad, n = Undecodable(), 0
    for msg, value in _rows(recording, keys, bad):
        out.write(json.dumps({"key": msg.key, "schema": msg.schema or None,
                              "log_time_ns": msg.log_time, "publish_time_ns": msg.publish_time,
                              "value": to_jsonable(value)}, separators=(",", ":")) + "\n")
        n += 1
    recording.problems.extend(bad.report())
    return n


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena export", description=__doc__)
    add_drive_arguments(parser)
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--csv", metavar="DIR", type=Path, help="one CSV file per key into DIR")
    what.add_argument("--json", metavar="FILE", nargs="?", const="-",
                      help="JSON lines into FILE (default stdout)")
    what.add_argument("--format", choices=["foxglove"],
                      help="foxglove: an MCAP file Foxglove and Lichtblick open (-o, default "
                           "DRIVE-foxglove.mcap): json/jsonschema channels plus LocationFix, "
                           "PoseInFrame, FrameTransform and Log (viena/foxglove_export.py)")
    parser.add_argument("-o", "--output", metavar="FILE", type=Path,
                        help="with --format: the file to write")
    parser.add_argument("--keyexpr", nargs="+", metavar="KEYEXPR",
                        help="export only keys these key expressions include")
    return parser


def _export_foxglove(recording: Source, output: Path | None, keys: KeyFilter) -> None:
    from viena.foxglove_export import default_output, export_foxglove

    # export_foxglove reads what a Source has (messages, metadata, path): a drive as a file
    done = export_foxglove(recording, output or default_output(recording.path), keys)
    print(f"exported {done.samples} samples as {done.messages} Foxglove messages into {done.path}",
          file=sys.stderr)
    for key, n in sorted(done.invalid.items()):
        recording.problems.append(f"{n} samples on {key} failed their schema: left out")


def run(args: argparse.Namespace) -> int:
    try:
        keys = KeyFilter(args.keyexpr)
        recording = open_source(args.file, args.drive, say=lambda note: print(f"viena export: {note}", file=sys.stderr))
        if args.format == "foxglove":
            _export_foxglove(recording, args.output, keys)
        elif args.csv is not None:
            counts = export_csv(recording, args.csv, keys)
            print(f"exported {sum(counts.values())} samples on {len(counts)} keys into {args.csv}/",
                  file=sys.stderr)
        elif args.json == "-":
            export_json(recording, sys.stdout, keys)
        else:
            with open(args.json, "w") as out:
                n = export_json(recording, out, keys)
            print(f"exported {n} samples into {args.json}", file=sys.stderr)
    except InputError as exc:
        print(f"viena export: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    except OSError as exc:
        print(f"viena export: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    for line in recording.report():
        print(f"viena export: {recording.path}: {line}", file=sys.stderr)
    return 1 if recording.stopped else 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
