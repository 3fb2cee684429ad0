"""The car's real drive of 2016-06-01, as the solutions its NovAtel receiver computed.

``data/novatel_bestxyz_drive_2016-06-01.csv`` holds 7634 BESTXYZ epochs decoded by the
old logger (10 Hz, 764 s, 130 INSUFFICIENT_OBS rows), with the host's local clock
(Lisbon summer time, UTC+1) instead of the receiver's GPS time, which it dropped.
The receiver's epochs were 100 ms apart on GPS time and reached the host 20-40 ms later,
so an epoch's GPS time is its host time (in UTC) rounded down to 100 ms: this gives
exactly one epoch per row, 100 ms apart, with the recording's one 1 s gap kept.

Fields the logger did not keep are filled the way this receiver sends them: position
type SINGLE (NONE without a fix), velocity type DOPPLER_VELOCITY (its V-latency is the
Doppler's 0.15 s), satellites tracked = satellites used, differential age 0.
"""
from __future__ import annotations

import calendar
import csv
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path

from viena.services.gnss.driver.gpstime import NS_PER_MS, utc_to_gps_ns
from viena.services.gnss.driver.novatel.enums import PositionType, SolutionStatus

from .solution import Solution

#: The recording, shipped in the repository's data/ folder.
DRIVE_CSV = Path(__file__).resolve().parents[3] / "data" / "novatel_bestxyz_drive_2016-06-01.csv"
#: The logger's clock: Lisbon summer time (WEST).
RECORDED_UTC_OFFSET_S = 3600
EPOCH_MS = 100


@dataclass(frozen=True)
class RecordedEpoch:
    index: int                      # the CSV's "Indice"
    host_utc_ns: int                # when the old logger received it
    solution: Solution


def _utc_ns(text: str, utc_offset_s: int) -> int:
    stamp = datetime.strptime(text.strip(), "%Y-%m-%d %H:%M:%S.%f")
    seconds = calendar.timegm(stamp.timetuple()) - utc_offset_s
    return seconds * 1_000_000_000 + stamp.microsecond * 1000


def _floats(row: dict, *names: str) -> tuple:
    return tuple(float(row[n]) for n in names)


def epoch_from_row(row: dict, utc_offset_s: int = RECORDED_UTC_OFFSET_S) -> RecordedEpoch:
    """One CSV row as the receiver computed it."""
    host_utc_ns = _utc_ns(row["Time"], utc_offset_s)
    gps_ms = utc_to_gps_ns(host_utc_ns) // NS_PER_MS // EPOCH_MS * EPOCH_MS
    pos_status = SolutionStatus(int(row["PSolStatus"]))
    vel_status = SolutionStatus(int(row["VSolStatus"]))
    fixed = pos_status == SolutionStatus.SOL_COMPUTED
    sats = int(row["SolSatNumber"])
    solution = Solution(
        gps_ms=gps_ms, pos_status=pos_status,
        pos_type=PositionType.SINGLE if fixed else PositionType.NONE,
        ecef_m=_floats(row, "X", "Y", "Z"), ecef_sigma_m=_floats(row, "stdX", "stdY", "stdZ"),
        vel_status=vel_status,
        vel_type=(PositionType.DOPPLER_VELOCITY if vel_status == SolutionStatus.SOL_COMPUTED
                  else PositionType.NONE),
        vel_ecef_mps=_floats(row, "VX", "VY", "VZ"),
        vel_sigma_mps=_floats(row, "stdVX", "stdVY", "stdVZ"),
        vel_latency_s=float(row["VLatency"]), sol_age_s=float(row["SolAge"]),
        sats_tracked=sats, sats_used=sats)
    return RecordedEpoch(int(row["Indice"]), host_utc_ns, solution)


def load_drive(path: str | Path = DRIVE_CSV, start: int = 0, stop: int | None = None,
               utc_offset_s: int = RECORDED_UTC_OFFSET_S) -> list[RecordedEpoch]:
    """Rows [start, stop) of a recording, in order."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f, skipinitialspace=True)
        rows = [row for i, row in enumerate(reader) if i >= start and (stop is None or i < stop)]
    return [epoch_from_row(row, utc_offset_s) for row in rows]


class DriveReplay:
    """Plays recorded epochs back at their recorded pace (times ``speed``).

    ``begin(now_s, gps_now_ms)`` starts it; ``due(now_s)`` returns the solutions whose
    time has come. With ``retime`` the epochs are moved to the present (whole 100 ms
    steps, and the start delayed so each keeps its recorded latency) so they mix with live
    data; without it they keep their 2016 GPS times. ``loop`` starts over at the end.
    """

    def __init__(self, epochs: list[RecordedEpoch], speed: float = 1.0, loop: bool = False,
                 retime: bool = True, undulation_m: float = 0.0):
        if not epochs:
            raise ValueError("nothing to replay")
        if speed <= 0:
            raise ValueError("replay speed must be positive")
        self.epochs = epochs
        self.speed = speed
        self.loop = loop
        self.retime = retime
        self.undulation_m = undulation_m    # the recording is ECEF; BESTPOS/GGA split height
        self.start_s: float | None = None
        self.index = 0
        self.shift_ms = 0
        self.last: Solution | None = None

    @property
    def started(self) -> bool:
        return self.start_s is not None

    @property
    def finished(self) -> bool:
        return self.started and self.index >= len(self.epochs)

    def host_gps_ms(self, index: int = 0) -> float:
        """When the old logger received an epoch, in GPS ms."""
        return utc_to_gps_ns(self.epochs[index].host_utc_ns) / NS_PER_MS

    def begin(self, now_s: float, gps_now_ms: float) -> None:
        if self.retime:
            gap_ms = gps_now_ms - self.host_gps_ms(0)
            self.shift_ms = int(-(-gap_ms // EPOCH_MS) * EPOCH_MS)      # ceil to 100 ms
            self.start_s = now_s + (self.shift_ms - gap_ms) / 1000.0
        else:
            self.shift_ms = 0
            self.start_s = now_s
        self.index = 0

    def time_of(self, index: int) -> float:
        assert self.start_s is not None, "asked only once begun"
        first = self.epochs[0].host_utc_ns
        return self.start_s + (self.epochs[index].host_utc_ns - first) / 1e9 / self.speed

    def next_time(self) -> float | None:
        if not self.started or self.finished:
            return None
        return self.time_of(self.index)

    def solution(self, index: int) -> Solution:
        solution = self.epochs[index].solution
        return replace(solution, gps_ms=solution.gps_ms + self.shift_ms,
                       undulation_m=self.undulation_m)

    def due(self, now_s: float) -> list[Solution]:
        out = []
        while self.started:
            while self.index < len(self.epochs) and self.time_of(self.index) <= now_s:
                self.last = self.solution(self.index)
                out.append(self.last)
                self.index += 1
            if not (self.finished and self.loop):
                break
            first, last = self.epochs[0], self.epochs[-1]
            span_s = (last.host_utc_ns - first.host_utc_ns) / 1e9 + EPOCH_MS / 1000.0
            assert self.start_s is not None, "finished: begun"
            self.start_s += span_s / self.speed
            self.shift_ms += last.solution.gps_ms - first.solution.gps_ms + EPOCH_MS
            self.index = 0
        return out
