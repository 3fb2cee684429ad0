"""`viena calibrate imu mount|time`: the IMU's mount and clock, measured from a recorded drive.

    viena record -o drive.mcap                     # park 10 s, then drive turns and speed changes
    viena calibrate imu time drive.mcap --unit razor0 --lever-arm -0.5 1.0 1.5
    viena calibrate imu mount drive.mcap --unit razor0 --lever-arm -0.5 1.0 1.5

Both read the unit's samples (their `raw` values, so the recording's own calibration does
not matter) and one GNSS receiver's fixes from an MCAP recording made by `viena record`.
`--lever-arm` is that receiver's antenna in the body frame (x right, y forward, z up, from
the rear axle): in a turn an antenna ahead of the axle moves sideways, which would look
like a time offset of a quarter of a second at walking pace.

`time` measures the offset to add to the unit's stamps (model/time_offset.py); the
recording's stamps already include the stored offset, so the stored value moves by what
was measured. `mount` measures the board-to-body rotation (model/mount.py); it first times
the board by its vertical rate, which needs no mount. Both print the figure and its
uncertainty, store it in the unit's table (unless --dry-run) and leave the file as it
was when the data cannot give a figure.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from viena.services.imu.model.calibration import ImuCalibration, SampleCalibrator
from viena.services.imu.model.fitting import FitError
from viena.services.imu.model.motion import GnssMotion, gnss_motion
from viena.services.imu.model.mount import estimate_mount, levelling
from viena.services.imu.model.time_offset import estimate_time_offset

PARKED_HINT = "park for 10 s at the start, then drive turns and speed changes for a minute or more"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, metavar="RECORDING.mcap",
                        help="a drive recorded by `viena record` with the unit's samples and GNSS fixes")
    parser.add_argument("--gnss", metavar="UNIT", help="which receiver's fixes (default: the first recorded)")
    parser.add_argument("--lever-arm", nargs=3, type=float, default=(0.0, 0.0, 0.0),
                        metavar=("X_M", "Y_M", "Z_M"),
                        help="the receiver's antenna in the body frame, from the rear axle (default 0 0 0)")


@dataclass
class DriveData:
    t_s: np.ndarray               # the unit's stamps as recorded, s
    raw_accel_g: np.ndarray
    raw_gyro_dps: np.ndarray
    fixes: list[dict]
    gnss_unit: str

    def motion(self, lever_arm_m) -> GnssMotion:
        return gnss_motion(self.fixes, lever_arm_m)

    def board(self, cal: ImuCalibration) -> tuple[np.ndarray, np.ndarray]:
        """Specific force and rates in the board's own axes, SI."""
        c = SampleCalibrator(cal.board_frame())
        return c.accel_array(self.raw_accel_g), c.gyro_array(self.raw_gyro_dps)

    def body(self, cal: ImuCalibration) -> tuple[np.ndarray, np.ndarray]:
        c = SampleCalibrator(cal)
        return c.accel_array(self.raw_accel_g), c.gyro_array(self.raw_gyro_dps)


def read_drive(path: Path, unit: str, gnss_unit: str | None) -> DriveData:
    """The unit's samples and one receiver's fixes from a recording."""
    from viena.recording import Recording

    samples, fixes_by_unit = [], {}
    for m in Recording(path).messages():
        parts = m.key.split("/")
        if len(parts) == 5 and parts[2] == "imu" and parts[3] == unit and parts[4] == "sample":
            samples.append(m.value())
        elif len(parts) == 5 and parts[2] == "gnss" and parts[4] == "fix":
            fixes_by_unit.setdefault(parts[3], []).append(m.value())
    if not samples:
        raise FitError(f"{path}: no samples of IMU unit '{unit}'")
    if not fixes_by_unit:
        raise FitError(f"{path}: no GNSS fixes")
    gnss_unit = gnss_unit or sorted(fixes_by_unit)[0]
    if gnss_unit not in fixes_by_unit:
        raise FitError(f"{path}: no fixes of GNSS unit '{gnss_unit}' (have {', '.join(sorted(fixes_by_unit))})")
    samples.sort(key=lambda s: s["t"])
    fixes = sorted(fixes_by_unit[gnss_unit], key=lambda f: f["t"])
    return DriveData(np.array([s["t"] for s in samples]) * 1e-9,
                     np.array([s["raw"]["accel_g"] for s in samples], float),
                     np.array([s["raw"]["gyro_dps"] for s in samples], float), fixes, gnss_unit)


def measure_time(drive: DriveData, cal: ImuCalibration, lever_arm_m) -> tuple[float, dict]:
    """(new stored offset, report): the residual offset of the recording, in the body frame."""
    try:
        accel, gyro = drive.body(cal)
        found = estimate_time_offset(drive.t_s, accel, gyro, drive.motion(lever_arm_m))
    except ValueError as exc:
        raise FitError(f"{exc} ({PARKED_HINT})") from None
    print(f"IMU clock against GNSS '{drive.gnss_unit}': {found}")
    new = cal.time_offset_s + found.offset_s
    print(f"time offset [s]  {new:+.4f}   (was {cal.time_offset_s:+.4f}; the recording was stamped with it)")
    return new, {"measured_s": round(found.offset_s, 5), "sigma_s": round(found.sigma_s, 5),
                 "correlation": round(found.correlation, 3), "gnss": drive.gnss_unit,
                 "driving_s": round(found.seconds_used, 1)}


def measure_mount(drive: DriveData, cal: ImuCalibration, lever_arm_m) -> tuple[ImuCalibration, dict]:
    try:
        motion = drive.motion(lever_arm_m)
        accel, gyro = drive.board(cal)
        # time the board first by its vertical rate (levelled by gravity, no mount needed)
        still = np.linalg.norm(gyro, axis=1) < 0.02
        level = levelling(accel[still].mean(axis=0)) if still.sum() > 100 else np.eye(3)
        timing = estimate_time_offset(drive.t_s, np.zeros_like(accel), gyro @ level.T, motion)
        found = estimate_mount(drive.t_s + timing.offset_s, accel, gyro, motion)
    except ValueError as exc:
        raise FitError(f"{exc} ({PARKED_HINT})") from None
    z, y, x = found.mount.zyx_deg
    print(f"mount zyx [deg]  z {z:+.2f}  y {y:+.2f}  x {x:+.2f}   (was {list(cal.mount_zyx_deg)})")
    print(f"  levelled on {found.parked_samples} parked samples; yaw from {found.moving_samples} "
          f"moving ones, +- {found.yaw_sigma_deg:.2f} deg (misfit {found.yaw_residual_mps2:.2f} m/s^2); "
          f"timed at {timing.offset_s * 1e3:+.0f} ms")
    report = {"yaw_sigma_deg": round(found.yaw_sigma_deg, 3), "residual_mps2": round(found.yaw_residual_mps2, 3),
              "parked_samples": found.parked_samples, "moving_samples": found.moving_samples,
              "gnss": drive.gnss_unit}
    return cal.with_mount(found.mount, report), report
