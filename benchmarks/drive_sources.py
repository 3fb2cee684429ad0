"""Where the estimator's real drives come from, and how each is converted (real_drive.py).

Each source names its home, its licence and its sensors. `fetch(name)` reads the files
from `--from DIR` (a clone, or a bare git directory, of the source's repository) or,
without it, downloads them from the repository on GitHub; converts them and stores the
drive in the drives directory. Nothing of them goes into viena's repository.

- `comma2k19` (github.com/commaai/comma2k19, MIT): a car on a highway, 60 s; a phone-grade
  MEMS IMU (comma EON) at 104 Hz; u-blox M8 fixes at 10 Hz; comma's INS/GNSS/vision pose
  at 20 Hz as the reference.
- `enav_canada` (the CSA/STARS enav planetary dataset, as NaveGo copies it: LGPL-3.0): a
  wheeled rover, 6 min, every heading; a MEMS IMU at 200 Hz; GPS fixes at 20 Hz; the
  dataset's global pose at 2.2 Hz as the reference.
- `gins_<imu>` (github.com/i2Nav-WHU/awesome-gins-datasets, no licence stated): a car, 27
  min, open sky; ICM20602, ADIS16460, ADIS16465 or HGuide i300; a post-processed
  reference per IMU. Its IMU archives are too large for some mirrors (see docs/estimator.md).

`sim` is not a real drive: the simulated car's drive with the device twins' IMU, in the
same shape, so the bench and its tests run on a fresh checkout without a download.
"""
from __future__ import annotations

import io
import subprocess
import urllib.parse
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from benchmarks.real_drive import DRIVES_DIR, RealDrive
from viena.services.gnss.driver import gpstime


class Files:
    """A source repository's files: from a work tree, a git directory, or GitHub."""

    def __init__(self, repo: str, rev: str, where: Path | None):
        self.repo, self.rev, self.where = repo, rev, where

    def read(self, path: str) -> bytes:
        if self.where is not None:
            plain = self.where / path
            if plain.is_file():
                return plain.read_bytes()
            done = subprocess.run(["git", "-C", str(self.where), "show", f"{self.rev}:{path}"],
                                  capture_output=True)
            if done.returncode == 0:
                return done.stdout
            raise FileNotFoundError(f"{self.where}: no {path} at {self.rev} ({done.stderr.decode().strip()})")
        url = f"https://raw.githubusercontent.com/{self.repo}/{self.rev}/{urllib.parse.quote(path)}"
        with urllib.request.urlopen(url, timeout=60) as r:        # noqa: S310 (a fixed https host)
            return r.read()


def _frd_to_body(v: np.ndarray) -> np.ndarray:
    """forward-right-down axes to viena's body frame (x right, y forward, z up)."""
    return np.column_stack([v[:, 1], v[:, 0], -v[:, 2]])


def _enu_of_ecef(ecef: np.ndarray, origin) -> np.ndarray:
    e, n, u = pymap3d.ecef2enu(ecef[:, 0], ecef[:, 1], ecef[:, 2], *origin)
    return np.column_stack([e, n, u])


# -- comma2k19 -----------------------------------------------------------------------------------
COMMA_SEGMENT = "Example_1/b0c9d2329ad1606b|2018-08-02--08-34-47/40/"


def comma2k19(where: Path | None) -> RealDrive:
    files = Files("commaai/comma2k19", "HEAD" if where else "master", where)

    def npy(p):
        return np.load(io.BytesIO(files.read(COMMA_SEGMENT + p)))

    t_imu = npy("processed_log/IMU/accelerometer/t")
    accel = npy("processed_log/IMU/accelerometer/value")
    # the gyro with the phone's own bias estimate taken off, as viena-imu sends a calibrated one
    t_gyro = npy("processed_log/IMU/gyro/t")
    gyro = npy("processed_log/IMU/gyro/value")
    gyro = np.column_stack([np.interp(t_imu, t_gyro, gyro[:, k]) for k in range(3)])
    t_ref = npy("global_pose/frame_times")
    gps_times = npy("global_pose/frame_gps_times")              # week, time of week
    p_ecef = npy("global_pose/frame_positions")
    v_ecef = npy("global_pose/frame_velocities")
    # boot time -> GPS time: the pose's own pairs (a constant offset)
    gps_s = gps_times[:, 0] * 604800.0 + gps_times[:, 1]
    boot_to_gps = float(np.median(gps_s - t_ref))
    t_start = float(max(t_imu[0], t_ref[0]))
    t0_ns = gps_to_utc_ns(t_start + boot_to_gps)
    origin = tuple(float(v) for v in pymap3d.ecef2geodetic(*p_ecef[0]))
    enu = _enu_of_ecef(p_ecef, origin)
    ve, vn, vu = pymap3d.uvw2enu(v_ecef[:, 0], v_ecef[:, 1], v_ecef[:, 2], origin[0], origin[1])
    t_gnss = npy("processed_log/GNSS/live_gnss_ublox/t")
    fix = npy("processed_log/GNSS/live_gnss_ublox/value")   # lat, lon, speed, utc ms, alt, bearing
    fe, fn, fu = pymap3d.geodetic2enu(fix[:, 0], fix[:, 1], fix[:, 4], *origin)
    bearing = np.radians(fix[:, 5])
    gnss_vel = np.column_stack([fix[:, 2] * np.sin(bearing), fix[:, 2] * np.cos(bearing), np.zeros(len(fix))])
    about = ("comma2k19 Example_1 segment 40 (github.com/commaai/comma2k19, MIT): a car on the I-280, "
             "60 s, straight\n"
             "IMU: the comma EON's phone-grade MEMS, 104 Hz (the gyro with the phone's bias estimate off); "
             "GNSS: u-blox M8 live fixes, 10 Hz\n"
             "reference: comma's tightly coupled INS/GNSS/vision pose (20 Hz), not independent of this IMU")
    return RealDrive("comma2k19", about, origin, t0_ns, t_imu - t_start, _frd_to_body(gyro),
                     _frd_to_body(accel), t_ref - t_start, enu, np.column_stack([ve, vn, vu]),
                     gnss_t_s=t_gnss - t_start, gnss_enu_m=np.column_stack([fe, fn, fu]),
                     gnss_vel_enu_mps=gnss_vel, gnss_sigma_m=(2.5, 2.5, 5.0))


def gps_to_utc_ns(gps_s: float) -> int:
    """GPS seconds since its epoch to ns UTC (the leap seconds of that date)."""
    week, sow = divmod(gps_s, 604800.0)
    ms = int(sow * 1e3)
    return gpstime.gps_to_utc_ns(int(week), ms) + int(round((sow * 1e3 - ms) * 1e6))


# -- the enav planetary rover, from NaveGo's copy -------------------------------------------------------
ENAV = "examples/visual-data/"


def enav_canada(where: Path | None) -> RealDrive:
    import scipy.io

    files = Files("rodralez/NaveGo", "HEAD" if where else "master", where)
    imu = scipy.io.loadmat(io.BytesIO(files.read(ENAV + "canada-planetary-data/data/imu_planetary.mat")),
                           squeeze_me=True, struct_as_record=False)["imu_planetary"]

    def table(p):
        return np.loadtxt(io.BytesIO(files.read(ENAV + "external-data/canada/gnss/" + p)), delimiter=",",
                          comments="#")

    gps_ll, gps_utm, pose = table("gps-latlong.txt"), table("gps-utm18t.txt"), table("global-pose-utm.txt")
    origin = (float(gps_ll[0, 1]), float(gps_ll[0, 2]), float(gps_ll[0, 3]))
    # UTM is conformal: over a few hundred metres ENU is an affine map of it, fitted on the
    # receiver's own fixes, which the dataset gives both ways
    e, n, u = pymap3d.geodetic2enu(gps_ll[:, 1], gps_ll[:, 2], gps_ll[:, 3], *origin)
    A = np.column_stack([gps_utm[:, 1] - gps_utm[0, 1], gps_utm[:, 2] - gps_utm[0, 2], np.ones(len(gps_utm))])
    coef, *_ = np.linalg.lstsq(A, np.column_stack([e, n]), rcond=None)

    def enu_of_utm(east, north, alt):
        xy = np.column_stack([east - gps_utm[0, 1], north - gps_utm[0, 2], np.ones(len(east))]) @ coef
        return np.column_stack([xy, alt - origin[2]])

    t_start = float(gps_ll[0, 0])
    t_ref = pose[:, 0] - t_start
    ref = enu_of_utm(pose[:, 1], pose[:, 2], pose[:, 3])
    vel = np.column_stack([np.gradient(ref[:, k], t_ref) for k in range(3)])
    # the reference's yaw (base_link x forward, about up from east) in viena's (from north)
    qx, qy, qz, qw = pose[:, 4], pose[:, 5], pose[:, 6], pose[:, 7]
    yaw_east = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    ref_yaw = np.unwrap(yaw_east - np.pi / 2)
    # forward-right-down, as NaveGo takes it: at rest the specific force is -g on z (down)
    gyro, accel = _frd_to_body(np.asarray(imu.wb, float)), _frd_to_body(np.asarray(imu.fb, float))
    t_imu = np.asarray(imu.t, float)
    # the IMU's times were rebuilt from its first sample: find its start on the reference's
    # clock by the turn rate both see
    t_imu = t_imu + _lag_by_yaw_rate(t_imu, gyro[:, 2], t_ref, ref_yaw)
    gnss = enu_of_utm(gps_utm[:, 1], gps_utm[:, 2], gps_utm[:, 3])
    about = ("enav planetary dataset (CSA / STARS lab), run 3, as copied into NaveGo (github.com/rodralez/NaveGo, "
             "LGPL-3.0): a wheeled rover, 6 min, every heading, up to 2.6 m/s\nIMU: MEMS, 200 Hz; GNSS: the "
             "rover's GPS fixes, 20 Hz\nreference: the dataset's global pose, 2.2 Hz")
    return RealDrive("enav_canada", about, origin, int(round(t_start * 1e9)), t_imu, gyro, accel,
                     t_ref, ref, vel, ref_yaw_t_s=t_ref, ref_yaw_rad=ref_yaw,
                     gnss_t_s=gps_ll[:, 0] - t_start, gnss_enu_m=gnss, gnss_vel_enu_mps=None,
                     gnss_sigma_m=(1.0, 1.0, 2.0))


def _lag_by_yaw_rate(t_imu, rate_z, t_ref, yaw_ref, search_s: float = 20.0) -> float:
    """The shift to add to t_imu that best lines the gyro's z rate up with the reference's."""
    grid = np.arange(t_ref[0], t_ref[-1], 0.1)
    ref_rate = np.gradient(np.interp(grid, t_ref, yaw_ref), grid)
    best, best_c = 0.0, -np.inf
    for lag in np.arange(-search_s, search_s, 0.02):
        g = np.interp(grid, t_imu + lag, rate_z, left=np.nan, right=np.nan)
        ok = ~np.isnan(g)
        if ok.sum() < len(grid) // 2:
            continue
        c = np.corrcoef(g[ok], ref_rate[ok])[0, 1]
        if c > best_c:
            best, best_c = lag, c
    return float(best)


# -- i2Nav's awesome-gins-datasets ----------------------------------------------------------------------
GINS_IMUS = {"icm20602": "ICM20602", "adis16460": "ADIS16460", "adis16465": "ADIS16465", "i300": "i300"}


def gins(imu_name: str) -> Callable[[Path | None], RealDrive]:
    folder = GINS_IMUS[imu_name]

    def convert(where: Path | None) -> RealDrive:
        try:
            import py7zr
        except ImportError:
            raise SystemExit("the gins drives come as .7z archives: pip install py7zr") from None
        files = Files("i2Nav-WHU/awesome-gins-datasets", "HEAD" if where else "main", where)
        with py7zr.SevenZipFile(io.BytesIO(files.read(f"{folder}/{folder}.7z"))) as z:
            members = z.readall()
        text = {name.rsplit("/", 1)[-1]: data.read() for name, data in members.items()}
        imu = np.loadtxt(io.BytesIO(next(v for k, v in text.items() if k.lower().endswith(".txt"))))
        nav = np.loadtxt(io.BytesIO(next(v for k, v in text.items() if k.lower().endswith(".nav"))))
        return from_i2nav(f"gins_{imu_name}", imu, nav,
                          f"awesome-gins-datasets (github.com/i2Nav-WHU/awesome-gins-datasets, no licence "
                          f"stated): a car, 27 min, open sky\nIMU: {folder}; reference: post-processed for "
                          f"this IMU with RTK")
    return convert


def from_i2nav(name: str, imu: np.ndarray, nav: np.ndarray, about: str) -> RealDrive:
    """i2Nav's text formats (KF-GINS, OB_GINS, awesome-gins-datasets): IMU rows of GPS
    seconds of week and FRD increments of angle (rad) and velocity (m/s); reference rows of
    week, seconds of week, lat, lon, h, v north, east, down, roll, pitch, yaw (deg)."""
    dt = np.diff(imu[:, 0], prepend=imu[0, 0] - np.median(np.diff(imu[:, 0])))
    keep = dt > 0
    imu, dt = imu[keep], dt[keep]
    gyro = _frd_to_body(imu[:, 1:4] / dt[:, None])
    accel = _frd_to_body(imu[:, 4:7] / dt[:, None])
    week = int(nav[0, 0])
    t_start = float(max(imu[0, 0], nav[0, 1]))
    origin = (float(nav[0, 2]), float(nav[0, 3]), float(nav[0, 4]))
    e, n, u = pymap3d.geodetic2enu(nav[:, 2], nav[:, 3], nav[:, 4], *origin)
    vel = np.column_stack([nav[:, 6], nav[:, 5], -nav[:, 7]])
    return RealDrive(name, about, origin, gps_to_utc_ns(week * 604800.0 + t_start), imu[:, 0] - t_start,
                     gyro, accel, nav[:, 1] - t_start, np.column_stack([e, n, u]), vel,
                     ref_yaw_t_s=nav[:, 1] - t_start, ref_yaw_rad=np.unwrap(-np.radians(nav[:, 10])))


# -- the simulated car ----------------------------------------------------------------------------------
def from_sim(duration_s: float = 300.0, seed: int = 1, name: str = "sim") -> RealDrive:
    """The simulated car's drive, IMU from the twins, the truth as the reference; the IMU
    sits at the body origin (lever arm 0), as on the public drives' references."""
    from benchmarks.simdrive import Drive, DriveSamples
    from viena.services.sim.model.truth import IST_ORIGIN

    drive = Drive(duration_s=duration_s, seed=seed, with_mag=False)
    t, gyro, accel, tr, pos, vel = [], [], [], [], [], []
    t0 = None
    for kind, sample, truth in DriveSamples(drive):
        if kind != "imu":
            continue
        t0 = truth.t_ns if t0 is None else t0
        t.append((sample["t"] - t0) * 1e-9)
        gyro.append(sample["gyro_radps"])
        accel.append(sample["accel_mps2"])
        tr.append((truth.t_ns - t0) * 1e-9)
        pos.append(truth.enu_m)
        vel.append(truth.vel_enu_mps)
    about = "the simulated car (campus loop, 3-5 m/s), the Razor twin's IMU: not a real drive"
    return RealDrive(name, about, tuple(IST_ORIGIN), t0, np.array(t), np.array(gyro), np.array(accel),
                     np.array(tr), np.array(pos), np.array(vel))


@dataclass(frozen=True)
class Source:
    name: str
    convert: Callable[[Path | None], RealDrive]


SOURCES: dict[str, Source] = {
    "comma2k19": Source("comma2k19", comma2k19),
    "enav_canada": Source("enav_canada", enav_canada),
    **{f"gins_{k}": Source(f"gins_{k}", gins(k)) for k in GINS_IMUS},
    "sim": Source("sim", lambda _: from_sim()),
}


def fetch(name: str, source_dir: Path | None = None, directory: Path = DRIVES_DIR) -> Path:
    """Convert drive `name` and store it; returns where."""
    try:
        source = SOURCES[name]
    except KeyError:
        raise SystemExit(f"no drive {name!r}; have {', '.join(SOURCES)}") from None
    return source.convert(source_dir).save(directory)
