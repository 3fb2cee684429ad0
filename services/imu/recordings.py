"""Recorded Razor frames as CSV, in the car's logger format (brtiberio/logger_AHRS):

    Index,Time,ID,accx,accy,accz,gyrox,gyroy,gyroz,magx,magy,magz,yaw,pitch,roll

accelerations in g, rates in deg/s, magnetometer in counts, angles in deg, all as the
firmware sent them (board axes, before any host calibration); Time is the host's clock
when the frame was read. The real parked-car recordings ship in data/imu/.
"""
from __future__ import annotations

import csv
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from viena.services.imu.driver import Reading

HEADER = ["Index", "Time", "ID", "accx", "accy", "accz", "gyrox", "gyroy", "gyroz",
          "magx", "magy", "magz", "yaw", "pitch", "roll"]
DATA_DIR = Path(__file__).resolve().parents[2] / "data" / "imu"
#: the real recordings of the parked car: traction motor without current, and at 0/10/20 Hz
PARKED = ("nocurrent", "speed_0hz", "speed_10hz", "speed_20hz")


@dataclass
class Recording:
    t_host_ns: np.ndarray       # int64, host read time
    board_id: np.ndarray        # int
    accel_g: np.ndarray         # N x 3
    gyro_dps: np.ndarray        # N x 3
    mag_counts: np.ndarray      # N x 3
    euler_deg: np.ndarray       # N x 3 (yaw, pitch, roll)
    name: str = ""

    def __len__(self) -> int:
        return len(self.accel_g)

    @property
    def rate_hz(self) -> float:
        """Mean frame rate over the recording (host times arrive in bursts; their span is fine)."""
        span = (self.t_host_ns[-1] - self.t_host_ns[0]) / 1e9
        return (len(self) - 1) / span if span > 0 else float("nan")

    def slice(self, s: slice) -> Recording:
        return Recording(self.t_host_ns[s], self.board_id[s], self.accel_g[s], self.gyro_dps[s],
                         self.mag_counts[s], self.euler_deg[s], self.name)


def parked_path(name: str) -> Path:
    if name not in PARKED:
        raise ValueError(f"unknown parked recording {name!r}; known: {', '.join(PARKED)}")
    return DATA_DIR / f"razor_parked_{name}.csv"


def load_recording(path: str | Path) -> Recording:
    """Read a CSV recording; ValueError names the file and line of anything malformed."""
    path = Path(path)
    times, ids, values = [], [], []
    with path.open(newline="") as f:
        reader = csv.reader(f)
        header = [h.strip() for h in next(reader, [])]
        if header != HEADER:
            raise ValueError(f"{path}: not a Razor recording (header {header[:4]}...)")
        for row in reader:
            if not row:
                continue
            try:
                times.append(row[1].strip())
                ids.append(int(float(row[2])))
                values.append([float(v) for v in row[3:15]])
            except (ValueError, IndexError):
                raise ValueError(f"{path}:{reader.line_num}: cannot read {row!r}") from None
            if len(values[-1]) != 12:
                raise ValueError(f"{path}:{reader.line_num}: expected 15 columns")
    v = np.array(values, float).reshape(-1, 12)
    t = np.array(times, dtype="datetime64[ns]").astype(np.int64)
    return Recording(t, np.array(ids, int), v[:, 0:3], v[:, 3:6], v[:, 6:9], v[:, 9:12], path.stem)


def load_parked(name: str) -> Recording:
    return load_recording(parked_path(name))


def joined(recordings: list[Recording]) -> Recording:
    """Several recordings as one, in the order given (their names joined by +)."""
    def col(name: str) -> np.ndarray:
        return np.concatenate([getattr(r, name) for r in recordings])
    return Recording(col("t_host_ns"), col("board_id"), col("accel_g"), col("gyro_dps"), col("mag_counts"),
                     col("euler_deg"), "+".join(r.name for r in recordings))


def from_readings(readings: Iterable[Reading], name: str = "") -> Recording:
    readings = list(readings)
    def col(get):
        return np.array([get(r.frame) for r in readings], float).reshape(-1, 3)
    return Recording(np.array([r.t_host_ns for r in readings], np.int64),
                     np.array([r.frame.board_id or 0 for r in readings], int),
                     col(lambda f: f.accel_g), col(lambda f: f.gyro_dps), col(lambda f: f.mag_counts),
                     col(lambda f: f.euler_deg or (np.nan,) * 3), name)


def save_recording(path: str | Path, rec: Recording) -> None:
    with Path(path).open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        stamps = np.array(rec.t_host_ns, dtype="datetime64[ns]").astype("datetime64[ms]").astype(str)
        for i in range(len(rec)):
            vals = [*rec.accel_g[i], *rec.gyro_dps[i], *rec.mag_counts[i], *rec.euler_deg[i]]
            w.writerow([i, stamps[i].replace("T", " "), int(rec.board_id[i]), *(f"{v:.6g}" for v in vals)])
