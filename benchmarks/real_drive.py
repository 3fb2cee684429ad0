"""A real GNSS/INS drive as the estimator's bench reads it: raw IMU, reference trajectory.

Public drives come in their authors' formats (benchmarks/drive_sources.py converts them);
once converted, every drive is this: IMU samples in viena's body frame (x right, y
forward, z up; rates in rad/s, specific force in m/s^2, +g up at rest), and a reference
trajectory of the IMU's own point in a local ENU frame about `origin`, all on one time
axis in seconds (`t0_ns` is its zero as ns UTC). Stored as one .npz per drive in the
drives directory (`VIENA_DRIVES_DIR`, default ~/.cache/viena/drives), never in the
repository (the sources' licences decide who may copy them; the fetch script gets them
from their home).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

DRIVES_DIR = Path(os.environ.get("VIENA_DRIVES_DIR", "~/.cache/viena/drives")).expanduser()
#: the car's Razor runs at 82.5 Hz; faster IMUs are averaged down to at most this
MAX_IMU_RATE_HZ = 100.0


@dataclass
class RealDrive:
    name: str
    about: str                          # source, licence, sensors: one line each
    origin: tuple                       # lat_deg, lon_deg, height_m of the ENU frame
    t0_ns: int                          # drive second 0, ns UTC
    t_imu_s: np.ndarray                 # (n,) each IMU sample's time
    gyro_radps: np.ndarray              # (n, 3) body frame
    accel_mps2: np.ndarray              # (n, 3) body frame
    t_ref_s: np.ndarray                 # (m,) reference epochs
    ref_enu_m: np.ndarray               # (m, 3) the IMU's point
    ref_vel_enu_mps: np.ndarray         # (m, 3)
    #: the reference's yaw (viena's: CCW from north, unwrapped), where it has one
    ref_yaw_t_s: np.ndarray | None = None
    ref_yaw_rad: np.ndarray | None = None
    #: the drive's own receiver, where it has one: its fixes in the same ENU frame, their
    #: velocity (None: positions only) and the sigmas to send with them
    gnss_t_s: np.ndarray | None = None
    gnss_enu_m: np.ndarray | None = None
    gnss_vel_enu_mps: np.ndarray | None = None
    gnss_sigma_m: tuple = (2.5, 2.5, 5.0)

    def t_ns(self, t_s: float) -> int:
        return self.t0_ns + int(round(t_s * 1e9))

    @property
    def duration_s(self) -> float:
        return float(min(self.t_imu_s[-1], self.t_ref_s[-1]) - max(self.t_imu_s[0], self.t_ref_s[0]))

    @property
    def imu_rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_imu_s)))

    def speed_at(self, t_s) -> np.ndarray:
        v = self.ref_vel_enu_mps
        return np.interp(t_s, self.t_ref_s, np.hypot(v[:, 0], v[:, 1]))

    def ref_at(self, t_s) -> np.ndarray:
        """The reference position at t_s (one time or an array: (3,) or (k, 3))."""
        t = np.atleast_1d(np.asarray(t_s, float))
        out = np.column_stack([np.interp(t, self.t_ref_s, self.ref_enu_m[:, k]) for k in range(3)])
        return out[0] if np.ndim(t_s) == 0 else out

    def yaw_at(self, t_s) -> np.ndarray:
        """The reference's yaw where it has one, else its course over ground (both viena's:
        CCW from north)."""
        if self.ref_yaw_rad is not None:
            return np.interp(t_s, self.ref_yaw_t_s, self.ref_yaw_rad)
        return self.course_at(t_s)

    def course_at(self, t_s) -> np.ndarray:
        """The reference course over ground, viena's yaw convention (CCW from north)."""
        v = self.ref_vel_enu_mps
        e = np.interp(t_s, self.t_ref_s, v[:, 0])
        n = np.interp(t_s, self.t_ref_s, v[:, 1])
        return np.arctan2(-e, n)

    def imu_samples(self, unit: str = "imu0", late_s: float = 0.0, mount_zyx_deg=None,
                    max_rate_hz: float = MAX_IMU_RATE_HZ) -> list[tuple[float, dict]]:
        """(true time s, viena.imu.sample/1) in time order. `late_s`: the stamps run that
        much after the true time; `mount_zyx_deg`: the board sits turned by this rotation
        (yaw, pitch, roll about z, x, y) that nobody told the estimator about."""
        t, g, a = self.t_imu_s, self.gyro_radps, self.accel_mps2
        k = max(1, int(math.floor(self.imu_rate_hz / max_rate_hz + 1e-6)))
        if k > 1:                        # average k samples into one (increments summed)
            n = len(t) // k * k
            t = t[:n].reshape(-1, k).mean(axis=1)
            g = g[:n].reshape(-1, k, 3).mean(axis=1)
            a = a[:n].reshape(-1, k, 3).mean(axis=1)
        if mount_zyx_deg is not None:
            from viena.services.imu.model.mount import Mount
            to_board = Mount(tuple(mount_zyx_deg)).matrix.T
            g = g @ to_board.T
            a = a @ to_board.T
        out = []
        for ti, gi, ai in zip(t.tolist(), g.tolist(), a.tolist()):
            out.append((ti, {"t": self.t_ns(ti + late_s), "unit": unit, "accel_mps2": ai,
                             "gyro_radps": gi, "mag_T": None}))
        return out

    # -- storage -------------------------------------------------------------------------------
    def save(self, directory: Path = DRIVES_DIR) -> Path:
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f"{self.name}.npz"
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "name"}
        np.savez_compressed(path, **{k: np.asarray(v) for k, v in arrays.items() if v is not None})
        return path


def load(name: str, directory: Path = DRIVES_DIR) -> RealDrive:
    path = directory / f"{name}.npz"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such drive; get it with `viena bench estimator --fetch {name}`")
    with np.load(path) as z:
        kw = {k: z[k] for k in z.files}
    kw["about"] = str(kw["about"])
    kw["origin"] = tuple(kw["origin"].tolist())
    kw["t0_ns"] = int(kw["t0_ns"])
    kw["gnss_sigma_m"] = tuple(kw["gnss_sigma_m"].tolist())
    return RealDrive(name, **kw)


def available(directory: Path = DRIVES_DIR) -> list[str]:
    return sorted(p.stem for p in directory.glob("*.npz")) if directory.exists() else []
