"""`viena record list [DIR]`: the drives the black box recorded in DIR, one row each.

    DRIVE                  START (UTC)          END (UTC)            DURATION  DISTANCE            SIZE      FILES
    viena-20260501-101203  2026-05-01 10:12:03  2026-05-01 11:12:07  1:00:04   12.31 km estimator  231.4 MB  12

The distance driven is the length of the estimator state's path (`enu_m`, where its
position is valid); a drive without estimator states takes the GNSS fixes' positions
(the receiver with the most fixes), else the simulated car's truth: the column says which.
Moves shorter than MIN_STEP_M are taken as noise of a standing car. A drive whose last
file is still `.part` is being written, or was cut short (a kill or a power cut: the
recorder repairs it at its next start). `--json` prints the same as a JSON list.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from viena.common.errors import InputError, SampleError
from viena.common.paths import drives_dir
from viena.common.recording import Drive, find_drives, human_bytes
from viena.common.samples import topics
from viena.common.samples.topics import topic_of_key
from viena.tool import Fail, guarded

#: a standing car's position wanders: a move shorter than this from the last counted point is noise
MIN_STEP_M = 0.5
#: positions are read this often per key (s of log time): the path's length, at a fraction of the decoding
STEP_S = 0.2
EARTH_RADIUS_M = 6_371_008.8
#: where the distance comes from, in order of preference
SOURCES = ("estimator", "gnss", "truth")


class Odometer:
    """Length of a path in a plane, in metres, counting only moves of MIN_STEP_M or more."""

    def __init__(self) -> None:
        self.m = 0.0
        self.points = 0
        self._last: tuple[float, float] | None = None

    def add(self, east: float, north: float) -> None:
        self.points += 1
        if self._last is not None:
            step = math.hypot(east - self._last[0], north - self._last[1])
            if step < MIN_STEP_M:
                return
            self.m += step
        self._last = (east, north)

    def restart(self) -> None:
        """The frame moved (a new ENU origin): the next point starts a new leg."""
        self._last = None


@dataclass
class Distance:
    """The three candidate paths of a drive, each followed as its samples come."""

    estimator: Odometer = field(default_factory=Odometer)
    truth: Odometer = field(default_factory=Odometer)
    gnss: dict[str, Odometer] = field(default_factory=dict)
    _origin: Any = None
    _gnss_origin: tuple[float, float] | None = None
    _due: dict[str, int] = field(default_factory=dict)

    def readers(self) -> dict[str, Callable[[str, dict], None]]:
        return {topics.ESTIMATOR_STATE.name: self._state, topics.GNSS_FIX.name: self._fix,
                topics.SIM_TRUTH.name: self._truth}

    def wants(self, key: str, log_time: int) -> bool:
        """Is this sample's position read (one per STEP_S of each key)?"""
        if log_time < self._due.get(key, 0):
            return False
        self._due[key] = log_time + int(STEP_S * 1e9)
        return True

    def _state(self, key: str, state: dict) -> None:
        if state.get("origin") != self._origin:
            self._origin = state.get("origin")
            self.estimator.restart()
        enu = state.get("enu_m")
        if state.get("position_valid") and enu:
            self.estimator.add(float(enu[0]), float(enu[1]))

    def _fix(self, key: str, fix: dict) -> None:
        lat, lon = fix.get("lat_deg"), fix.get("lon_deg")
        if not fix.get("valid") or lat is None or lon is None:
            return
        if self._gnss_origin is None:
            self._gnss_origin = (lat, lon)
        lat0, lon0 = self._gnss_origin
        east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        self.gnss.setdefault(key, Odometer()).add(east, math.radians(lat - lat0) * EARTH_RADIUS_M)

    def _truth(self, key: str, truth: dict) -> None:
        enu = truth.get("enu_m")
        if enu:
            self.truth.add(float(enu[0]), float(enu[1]))

    def best(self) -> tuple[float | None, str | None]:
        """(metres, which source): the first source in SOURCES that saw the car move or stand."""
        gnss = max(self.gnss.values(), key=lambda o: o.points, default=Odometer())
        for name, odometer in zip(SOURCES, (self.estimator, gnss, self.truth)):
            if odometer.points >= 2:
                return odometer.m, name
        return None, None


@dataclass
class DriveRow:
    """One line of the list."""

    drive: str
    directory: str
    files: int
    bytes: int
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    distance_m: float | None
    distance_from: str | None
    cut_short: bool
    problems: list[str]


def drive_row(drive: Drive) -> DriveRow:
    """Read a whole drive once: its span, size and the distance driven."""
    distance = Distance()
    readers, reader_of = distance.readers(), {}
    for m in drive.messages():
        if m.key not in reader_of:               # the key's topic, looked up once a key
            found = topic_of_key(m.key)
            reader_of[m.key] = None if found is None else readers.get(found[0].name)
        reader = reader_of[m.key]
        if reader is None or not distance.wants(m.key, m.log_time):
            continue
        try:
            value = m.value()
        except SampleError:
            continue
        if isinstance(value, dict):
            reader(m.key, value)
    first, last = drive.first_log_time, drive.last_log_time
    metres, source = distance.best()
    return DriveRow(drive.id, str(drive.files[0].parent), len(drive.files), drive.size, first, last,
                    (last - first) / 1e9 if first is not None and last is not None else 0.0,
                    metres, source, drive.cut_short, drive.report())


def _utc(ns: int | None) -> str:
    return "-" if ns is None else datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S")


def _duration(s: float) -> str:
    whole = round(s)
    return f"{whole // 3600}:{whole % 3600 // 60:02d}:{whole % 60:02d}"


def _distance(row: DriveRow) -> str:
    if row.distance_m is None:
        return "-"
    text = f"{row.distance_m / 1000:.2f} km" if row.distance_m >= 1000 else f"{row.distance_m:.0f} m"
    return f"{text} {row.distance_from}"


def print_table(rows: list[DriveRow]) -> None:
    head = ["DRIVE", "START (UTC)", "END (UTC)", "DURATION", "DISTANCE", "SIZE", "FILES", ""]
    cells = [[r.drive, _utc(r.start_ns), _utc(r.end_ns), _duration(r.duration_s), _distance(r),
              human_bytes(r.bytes), str(r.files),
              "cut short (.part: still being written, or stopped)" if r.cut_short else ""] for r in rows]
    widths = [max(len(c[i]) for c in [head, *cells]) for i in range(len(head))]
    for line in [head, *cells]:
        print("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip())


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena record list", description=__doc__,
                                               formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("directory", nargs="?", type=Path, default=None, metavar="DIR",
                        help="where the drives are (default $VIENA_DRIVES, else ~/.local/share/viena/drives)")
    parser.add_argument("--json", action="store_true", help="the same as a JSON list, one object a drive")
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena record list", _run, args)


def _run(args: argparse.Namespace) -> int:
    directory = args.directory or drives_dir()          # $VIENA_DRIVES, else ~/.local/share/viena/drives
    try:
        rows = [drive_row(Drive(drive_id, files)) for drive_id, files in find_drives(directory).items()]
    except InputError as exc:
        raise Fail(str(exc), 2) from None
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=1))
    elif not rows:
        print(f"no drives in {directory}", file=sys.stderr)
    else:
        print_table(rows)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
