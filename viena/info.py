"""`viena info RECORDING`: what a recording holds, as `ros2 bag info` says it. RECORDING is one
file, or a drive of the black box (its directory or id) taken whole, each sample once.

    file      drive.mcap (4.1 MB, complete)
    recorded  2026-05-01T10:12:03+00:00 on viena-pi: `viena record viena/**`, car elettra
    duration  312.4 s, 2026-05-01 10:12:03.120 to 10:17:15.520 UTC
    samples   48,213 on 9 keys

    KEY                              SCHEMA                  COUNT   RATE Hz   NOMINAL   SIZE
    viena/elettra/estimator/state    viena.estimator.state/2 31240   100.0     82.5      2.9 MB

then, for the GNSS fixes and the corrections, what they carried (the solution types and
the corrections' age; the correction bytes a second and RTCM message types: as `viena hz`
says them live):

    KEY                              CONTENT
    viena/elettra/gnss/gnss0/fix     NARROW_INT 92 %, NARROW_FLOAT 8 % (fixed 92 %, float 8 %);
                                     diff age p50 1.0 s, max 1.9 s; base 0042

then whatever could not be read (a recording cut short or damaged is read as far as it
goes; the exit status is then 1). Rates are counts over each key's own span of log times.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from datetime import UTC, datetime

from viena.common.errors import InputError, SampleError
from viena.common.recording import Drive, Source, decode_value, human_bytes, open_source
from viena.common.samples.topics import topic_of_key
from viena.hz import CorrectionsMix, SolutionMix, content_mix
from viena.tool import Fail, add_drive_arguments, guarded


@dataclass
class KeyStats:
    schema: str
    count: int = 0
    bytes: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    #: what the samples carried, for the keys that say more than their rate (fixes, corrections)
    content: SolutionMix | CorrectionsMix | None = None

    def add(self, log_time: int, n_bytes: int) -> None:
        self.count += 1
        self.bytes += n_bytes
        self.first_ns = log_time if self.first_ns is None else min(self.first_ns, log_time)
        self.last_ns = log_time if self.last_ns is None else max(self.last_ns, log_time)

    @property
    def rate_hz(self) -> float | None:
        if self.first_ns is None or self.last_ns is None or self.count < 2 or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) / 1e9)


def summarize(recording: Source) -> dict[str, KeyStats]:
    """Per key: schema, count, bytes and span, read through the whole file; and what the
    fixes and corrections carried."""
    keys: dict[str, KeyStats] = {}
    for m in recording.messages():
        stats = keys.get(m.key)
        if stats is None:
            stats = keys[m.key] = KeyStats(m.schema or m.encoding, content=content_mix(m.schema, window=None))
        stats.add(m.log_time, len(m.data))
        if stats.content is not None:
            try:
                stats.content.add(decode_value(m.data, m.encoding))
            except SampleError:
                pass                # counted, not read: a damaged sample says nothing here
    return dict(sorted(keys.items()))


def nominal_hz(key: str) -> float | None:
    """The simulated car's rate of the key's topic (common/samples/topics.py), if it has one."""
    found = topic_of_key(key)
    return None if found is None else found[0].nominal_hz


def _utc(ns: int | None, fmt: str = "%Y-%m-%d %H:%M:%S.%f") -> str:
    if ns is None:
        return "-"
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime(fmt)[:-3]


def _drive_fields(recording: Source) -> dict:
    """For a drive: its id and files (a file alone has neither)."""
    if not isinstance(recording, Drive):
        return {}
    return {"drive": recording.id, "files": [str(p) for p in recording.files], "cut_short": recording.cut_short}


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena info", description=__doc__)
    add_drive_arguments(parser)
    parser.add_argument("--json", action="store_true", help="the same as one JSON object")
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena info", _run, args)


def _run(args: argparse.Namespace) -> int:
    try:
        recording = open_source(args.file, args.drive, say=lambda note: print(f"viena info: {note}", file=sys.stderr))
        keys = summarize(recording)
    except InputError as exc:
        raise Fail(str(exc), 2) from None
    first, last = recording.first_log_time, recording.last_log_time
    duration_s = (last - first) / 1e9 if first is not None and last is not None else 0.0
    problems = recording.report()
    if args.json:
        print(json.dumps({
            "file": str(recording.path), **_drive_fields(recording), "bytes": recording.size,
            "complete": recording.complete, "metadata": recording.metadata, "start_ns": first, "end_ns": last,
            "duration_s": duration_s, "samples": recording.count, "problems": problems,
            "keys": {k: {"schema": s.schema, "count": s.count, "bytes": s.bytes, "rate_hz": s.rate_hz,
                         "nominal_hz": nominal_hz(k),
                         **({"content": s.content.summary()} if s.content is not None else {})}
                     for k, s in keys.items()}}, indent=1))
        return 1 if problems else 0
    meta = recording.metadata
    state = "complete" if recording.complete and not problems else "INCOMPLETE: see below"
    print(f"file      {recording.path} ({human_bytes(recording.size)}, {state})")
    if isinstance(recording, Drive):
        print(f"drive     {recording.id}: {len(recording.files)} files, {recording.repeats} latched repeats "
              f"read once{', cut short (last file .part)' if recording.cut_short else ''}")
    if meta:
        print(f"recorded  {meta.get('started', '?')} on {meta.get('host', '?')}: "
              f"`viena record {meta.get('keyexprs', '')}`, car {meta.get('car', '?')}")
    print(f"duration  {duration_s:.1f} s, {_utc(first)} to {_utc(last)} UTC")
    print(f"samples   {recording.count:,} on {len(keys)} keys")
    if keys:
        width = max(len("KEY"), *(len(k) for k in keys))
        swidth = max(len("SCHEMA"), *(len(s.schema) for s in keys.values()))
        print(f"\n{'KEY':<{width}}  {'SCHEMA':<{swidth}}  {'COUNT':>8}  {'RATE Hz':>8}  {'NOMINAL':>8}  {'SIZE':>9}")
        for key, s in keys.items():
            rate = "-" if s.rate_hz is None else f"{s.rate_hz:.1f}"
            nominal = "-" if (n := nominal_hz(key)) is None else f"{n:g}"
            print(f"{key:<{width}}  {s.schema:<{swidth}}  {s.count:>8}  {rate:>8}  {nominal:>8}  "
                  f"{human_bytes(s.bytes):>9}")
        said = {key: s.content.line() for key, s in keys.items() if s.content is not None}
        if said:
            print(f"\n{'KEY':<{width}}  CONTENT")
            for key, line in said.items():
                print(f"{key:<{width}}  {line}")
    for line in problems:
        print(f"viena info: {recording.path}: {line}", file=sys.stderr)
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
