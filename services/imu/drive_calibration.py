"""`viena calibrate imu mount|time`: the IMU's mount and clock, measured from a recorded drive.

    viena record -o drive.mcap                     # drive turns and speed changes for a few minutes
    viena calibrate imu mount drive.mcap --unit razor0 --lever-arm -0.5 1.0 1.5
    viena calibrate imu time drive.mcap --unit razor0 --lever-arm -0.5 1.0 1.5

Both read the unit's samples (their `raw` values, so the recording's own calibration does
not matter) and one GNSS receiver's fixes from an MCAP recording made by `viena record`,
at any fix rate (1 Hz and up); a receiver without velocities gets them from its positions.
`--lever-arm` is that receiver's antenna in the body frame (x right, y forward, z up, from
the rear axle): in a turn an antenna ahead of the axle moves sideways, which would look
like a time offset of a quarter of a second at walking pace.

Either command does the same work, in the board's own axes, so neither needs the other
first: it times the board against the GNSS (model/time_offset.py: its up axis from
gravity, a coarse search over +-5 s, then a fine one; a best match at the search's edge,
or two about as good, is refused), then takes the lever arm's slip out with the timed
gyro and times it again, then measures the board-to-body rotation on the timed data
(model/mount.py: the road's slope from the GNSS's climb, so parking on a slope does not
tilt it). `time` stores the offset; `mount` stores the mount and the offset measured
with it. The recording's stamps already include the offset stored when it was recorded,
so the stored value moves by what was measured (measuring the same recording again
replaces what it measured before, rather than adding to it). A figure whose uncertainty
(a block bootstrap over the drive) is above --max-sigma-ms or --max-sigma-deg is not
stored, and the reason is given.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from viena.services.imu.model.calibration import MAX_TIME_OFFSET_S, ImuCalibration, SampleCalibrator
from viena.services.imu.model.fitting import FitError
from viena.services.imu.model.motion import GnssMotion, ImuTrack, at_rest, gnss_motion
from viena.services.imu.model.mount import MountEstimate, estimate_mount
from viena.services.imu.model.time_offset import MAX_OFFSET_S, TimeOffsetEstimate, estimate_time_offset

DRIVE_HINT = "drive turns and speed changes above walking pace for a few minutes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, metavar="RECORDING.mcap",
                        help="a drive recorded by `viena record` with the unit's samples and GNSS fixes")
    parser.add_argument("--gnss", metavar="UNIT", help="which receiver's fixes (default: the first recorded)")
    parser.add_argument("--lever-arm", nargs=3, type=float, default=(0.0, 0.0, 0.0),
                        metavar=("X_M", "Y_M", "Z_M"),
                        help="the receiver's antenna in the body frame, from the rear axle (default 0 0 0)")
    parser.add_argument("--max-offset-s", type=float, default=MAX_OFFSET_S,
                        help=f"how far off the IMU's clock may be, either way (default {MAX_OFFSET_S:g})")
    parser.add_argument("--max-sigma-ms", type=float, default=Limits.max_sigma_ms,
                        help=f"store no clock offset less sure than this (default {Limits.max_sigma_ms:g})")
    parser.add_argument("--max-sigma-deg", type=float, default=Limits.max_sigma_deg,
                        help=f"store no mount less sure than this (default {Limits.max_sigma_deg:g})")


@dataclass(frozen=True)
class Limits:
    """What the commands accept: how far to search for the clock, how sure a result must be."""

    max_offset_s: float = MAX_OFFSET_S
    max_sigma_ms: float = 20.0
    max_sigma_deg: float = 0.5

    @classmethod
    def of(cls, args) -> Limits:
        return cls(*(getattr(args, name, default) for name, default in
                     (("max_offset_s", cls.max_offset_s), ("max_sigma_ms", cls.max_sigma_ms),
                      ("max_sigma_deg", cls.max_sigma_deg))))


@dataclass
class DriveData:
    t_s: np.ndarray               # the unit's stamps as recorded, s
    raw_accel_g: np.ndarray
    raw_gyro_dps: np.ndarray
    fixes: list[dict]
    gnss_unit: str

    def motion(self, lever_arm_m) -> GnssMotion:
        return gnss_motion(self.fixes, lever_arm_m)

    @property
    def fingerprint(self) -> str:
        """Which recording this is (its first stamp and its number of samples): measured
        again, its stamps are still those of the offset stored when it was recorded."""
        return f"{int(round(self.t_s[0] * 1e9))}+{len(self.t_s)}"

    def stamped_with(self, cal: ImuCalibration) -> float:
        """The offset the recording was stamped with: the stored one, less what this same
        recording measured before (so measuring it again replaces that, adds nothing)."""
        timing = cal.info.get("timing", {})
        if isinstance(timing, dict) and timing.get("recording") == self.fingerprint:
            return cal.time_offset_s - float(timing.get("measured_s", 0.0))
        return cal.time_offset_s

    def board(self, cal: ImuCalibration) -> tuple[np.ndarray, np.ndarray]:
        """Specific force and rates in the board's own axes, SI."""
        c = SampleCalibrator(cal.board_frame())
        return c.accel_array(self.raw_accel_g), c.gyro_array(self.raw_gyro_dps)

    def body(self, cal: ImuCalibration) -> tuple[np.ndarray, np.ndarray]:
        c = SampleCalibrator(cal)
        return c.accel_array(self.raw_accel_g), c.gyro_array(self.raw_gyro_dps)


def read_drive(path: Path, unit: str, gnss_unit: str | None) -> DriveData:
    """The unit's samples and one receiver's fixes from a recording."""
    from viena.common.recording import Recording

    samples: list[dict] = []
    fixes_by_unit: dict[str, list[dict]] = {}
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


@dataclass(frozen=True)
class DriveFit:
    timing: TimeOffsetEstimate
    motion: GnssMotion             # with the lever arm's slip from the timed gyro
    accel_board: np.ndarray
    gyro_board: np.ndarray


def time_drive(drive: DriveData, cal: ImuCalibration, lever_arm_m, limits: Limits = Limits()) -> DriveFit:
    """The board timed against the GNSS, twice: the second time with the lever arm's slip
    taken out by the timed gyro's turn rate (the fixes' own is late by half their interval)."""
    accel, gyro = drive.board(cal)
    try:
        first = drive.motion(lever_arm_m)
        rough = estimate_time_offset(drive.t_s, accel, gyro, first, max_offset_s=limits.max_offset_s)
        rest = at_rest(drive.t_s, accel, gyro, first, rough.offset_s)
        track = ImuTrack(drive.t_s + rough.offset_s, accel, gyro, rest.up, rest.gyro_bias)
        motion = gnss_motion(drive.fixes, lever_arm_m, turn_rate=track.rate)
        timing = estimate_time_offset(drive.t_s, accel, gyro, motion, around_s=rough.offset_s)
    except ValueError as exc:
        raise FitError(f"{exc} ({DRIVE_HINT})") from None
    timing = replace(timing, runner_up_s=rough.runner_up_s, runner_up_ratio=rough.runner_up_ratio)
    return DriveFit(timing, motion, accel, gyro)


def timing_report(drive: DriveData, found: TimeOffsetEstimate) -> dict:
    return {"measured_s": round(float(found.offset_s), 5), "sigma_s": round(float(found.sigma_s), 5),
            "correlation": round(float(found.correlation), 3), "gnss": drive.gnss_unit,
            "driving_s": round(float(found.seconds_used), 1), "fix_interval_s": round(float(found.fix_interval_s), 3),
            "recording": drive.fingerprint}


def _check_timing(found: TimeOffsetEstimate, limits: Limits, new_s: float) -> str | None:
    """Why the offset may not be stored, or None."""
    if abs(new_s) > MAX_TIME_OFFSET_S:
        return (f"the clock offset {new_s:+.3f} s is beyond the +-{MAX_TIME_OFFSET_S:g} s a calibration file holds: "
                f"set the IMU's clock, or stamp its samples on arrival")
    if found.sigma_s * 1e3 > limits.max_sigma_ms:
        return (f"the clock offset {found.offset_s * 1e3:+.0f} ms is uncertain by +- {found.sigma_s * 1e3:.0f} ms, "
                f"more than --max-sigma-ms {limits.max_sigma_ms:g}: {DRIVE_HINT}")
    return None


def measure_time(drive: DriveData, cal: ImuCalibration, lever_arm_m,
                 limits: Limits = Limits()) -> tuple[float, dict]:
    """(new stored offset, report): the residual offset of the recording."""
    found = time_drive(drive, cal, lever_arm_m, limits).timing
    print(f"IMU clock against GNSS '{drive.gnss_unit}': {found}")
    _print_runner_up(found)
    stamped = drive.stamped_with(cal)
    new = stamped + found.offset_s
    refused = _check_timing(found, limits, new)
    if refused:
        raise FitError(refused)
    print(f"time offset [s]  {new:+.4f}   (was {cal.time_offset_s:+.4f}; the recording was stamped with "
          f"{stamped:+.4f})")
    return new, timing_report(drive, found)


def _print_runner_up(found: TimeOffsetEstimate) -> None:
    if found.runner_up_s is not None:
        print(f"  next best match at {found.runner_up_s:+.2f} s, with {found.runner_up_ratio:.1f} times the misfit")


def measure_mount(drive: DriveData, cal: ImuCalibration, lever_arm_m,
                  limits: Limits = Limits()) -> tuple[ImuCalibration, dict]:
    """(calibration with the mount, and the clock offset measured with it when it is sure
    enough; report). Refused (FitError) when the mount is less sure than the limit."""
    fit = time_drive(drive, cal, lever_arm_m, limits)
    timing = fit.timing
    try:
        found = estimate_mount(drive.t_s + timing.offset_s, fit.accel_board, fit.gyro_board, fit.motion)
    except ValueError as exc:
        raise FitError(f"{exc} ({DRIVE_HINT})") from None
    _print_mount(found, cal, timing)
    if found.sigma_deg > limits.max_sigma_deg:
        raise FitError(f"the mount is uncertain by +- {found.sigma_deg:.2f} deg (tilt {found.tilt_sigma_deg:.2f}, "
                       f"yaw {found.yaw_sigma_deg:.2f}), more than --max-sigma-deg {limits.max_sigma_deg:g}: "
                       f"{DRIVE_HINT}")
    report = {**{name: round(float(getattr(found, name)), 3) for name in
                 ("sigma_deg", "tilt_sigma_deg", "yaw_sigma_deg", "residual_mps", "driving_s")},
              "level": found.level, "stops": len(found.stops), "timed_s": round(float(timing.offset_s), 4),
              "gnss": drive.gnss_unit}
    calibrated = cal.with_mount(found.mount, report)
    new = drive.stamped_with(cal) + timing.offset_s
    refused = _check_timing(timing, limits, new)
    if refused:
        print(f"time offset not stored: {refused}")
    else:
        print(f"time offset [s]  {new:+.4f}   (was {cal.time_offset_s:+.4f}; measured with the mount, stored too)")
        calibrated = calibrated.with_time_offset(new, timing_report(drive, timing))
    return calibrated, report


def _print_mount(found: MountEstimate, cal: ImuCalibration, timing: TimeOffsetEstimate) -> None:
    z, y, x = found.mount.zyx_deg
    print(f"mount zyx [deg]  z {z:+.2f}  y {y:+.2f}  x {x:+.2f}   (was {list(cal.mount_zyx_deg)})")
    print(f"  +- {found.sigma_deg:.2f} deg (tilt {found.tilt_sigma_deg:.2f}, yaw {found.yaw_sigma_deg:.2f}), "
          f"from {found.driving_s:.0f} s of driving (misfit {found.residual_mps:.2f} m/s a second); "
          f"IMU clock {timing}")
    if found.level == "driving":
        print("  level from driving: the road's slope from the GNSS's climb, its bank taken as level on average")
    else:
        print(f"  level from {found.level} at one place (slope and bank cancel)")
    for stop in found.stops:
        print(f"  {stop}")
