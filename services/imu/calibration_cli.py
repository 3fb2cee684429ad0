"""`viena calibrate imu`: fit a unit's calibration from recorded or live frames, show it,
store it in the unit's table of the calibration TOML file that viena-imu loads.

    viena calibrate imu accel six_poses.csv --unit razor0     # six-position (docs/sensors.md)
    viena calibrate imu gyro --port /dev/ttyUSB0 --seconds 20 # still period, from the device
    viena calibrate imu mag --live --seconds 120              # circles, from the running service
    viena calibrate imu time drive.mcap --lever-arm -0.5 1 1.5 # clock against GNSS, from a drive
    viena calibrate imu mount drive.mcap --lever-arm -0.5 1 1.5 # board to body rotation, from a drive
    viena calibrate imu noise parked.csv --plot allan.png     # Allan figures of a parked recording
    viena calibrate imu show --unit razor0
    viena calibrate imu record out.csv --port /dev/ttyUSB0 --seconds 60

Input: CSV recordings in the car's logger format, or `--port URL` (the device itself,
viena-imu not running), or `--live` (the raw values in viena-imu's samples over zenoh).
A fit that fails says why and leaves the stored calibration as it was (exit status 1).
"""
from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path

import numpy as np

from viena.common import clock
from viena.common.errors import ConfigError, InputError, SampleError
from viena.services.imu import drive_calibration, noise_calibration
from viena.services.imu.calibration_file import DEFAULT_FILE, dumps, load_calibration, load_file, save_calibration
from viena.services.imu.model import fitting
from viena.services.imu.model.calibration import FIRMWARES, ImuCalibration, SampleCalibrator, to_table
from viena.services.imu.model.fitting import FitError
from viena.services.imu.model.glitch import LISBON_FIELD_T, MagGlitchFilter
from viena.services.imu.recordings import (
    PARKED,
    Recording,
    from_readings,
    joined,
    load_parked,
    load_recording,
    save_recording,
)

DEFAULT_SECONDS = {"accel": 90.0, "gyro": 20.0, "mag": 120.0, "record": 60.0}
NOMINAL_RATE_HZ = 82.5
LISBON_INCLINATION_DEG = 52.77          # docs/frames.md#magnetic-field-in-lisbon


def build_parser() -> argparse.ArgumentParser:
    from viena.common.session import add_common_arguments

    parser = argparse.ArgumentParser(prog="viena calibrate imu", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--unit", default="razor0", help="which unit (default razor0)")
    common.add_argument("--firmware", choices=FIRMWARES,
                        help="what the board runs (default: as stored for the unit, else viena)")
    common.add_argument("--file", type=Path, default=DEFAULT_FILE,
                        help=f"calibration TOML (default {DEFAULT_FILE})")

    source = argparse.ArgumentParser(add_help=False)
    g = source.add_argument_group("where the frames come from (one of)")
    g.add_argument("recordings", nargs="*", type=Path, metavar="RECORDING.csv",
                   help="recordings in the car's logger CSV format")
    g.add_argument("--port", metavar="URL", help="read the device directly (pyserial URL)")
    g.add_argument("--live", action="store_true",
                   help="collect the raw values from the running viena-imu over zenoh")
    g.add_argument("--seconds", type=float, help="how long to collect from --port or --live")
    g.add_argument("--save-recording", type=Path, metavar="FILE",
                   help="also keep what was collected live, as CSV")
    add_common_arguments(source)

    fit = argparse.ArgumentParser(add_help=False)
    fit.add_argument("--dry-run", action="store_true", help="fit and report, store nothing")

    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("accel", parents=[common, source, fit],
                   help="accelerometer gains and offsets from six resting poses")
    sub.add_parser("gyro", parents=[common, source, fit], help="gyro bias from a still period")
    m = sub.add_parser("mag", parents=[common, source, fit],
                       help="magnetometer hard and soft iron from turning in circles")
    m.add_argument("--method", choices=("auto", "ellipse-2d", "ellipsoid-3d"), default="auto",
                   help="auto: the 3-D ellipsoid when the data span 3-D, else the 2-D ellipse")
    for name, what in (("mount", "the board-to-body rotation, from a recorded drive with GNSS"),
                       ("time", "the offset of the unit's timestamps, from a recorded drive with GNSS")):
        drive_calibration.add_arguments(sub.add_parser(name, parents=[common, fit], help=what,
                                                       description=drive_calibration.__doc__,
                                                       formatter_class=argparse.RawDescriptionHelpFormatter))
    n = sub.add_parser("noise", parents=[common, fit], description=noise_calibration.__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       help="Allan noise figures (N, B, K, Q) from parked recordings")
    n.add_argument("recordings", nargs="+", type=Path, metavar="RECORDING.csv",
                   help="parked recordings of the unit in the car's logger CSV format (several: pooled), "
                        f"or the car's own by name: {', '.join(PARKED)}")
    n.add_argument("--plot", type=Path, metavar="PNG", help="also draw the Allan deviation here")
    sub.add_parser("show", parents=[common], help="print the unit's calibration")
    r = sub.add_parser("record", parents=[common, source], help="record frames to CSV")
    r.add_argument("out", type=Path, help="CSV file to write")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except FitError as exc:
        print(f"calibration not changed: {exc}", file=sys.stderr)
        return 1
    except (InputError, ValueError, OSError) as exc:
        print(f"viena calibrate imu: {exc}", file=sys.stderr)
        return 2


# -- commands -------------------------------------------------------------------------------
def cmd_show(args) -> int:
    cal, how = _previous(args)
    print(f"# {how}")
    print(dumps({args.unit: to_table(cal)}, header=False))
    return 0


def cmd_record(args) -> int:
    rec = gather(args)
    save_recording(args.out, rec)
    print(f"{len(rec)} frames written to {args.out}")
    return 0


def cmd_accel(args) -> int:
    previous, how = _previous(args)
    rec = gather(args)
    fit = fit_accel(rec, previous)
    report_accel(fit, previous)
    return _store(args, previous.with_accel(fit), how)


def cmd_gyro(args) -> int:
    previous, how = _previous(args)
    fit = fit_gyro(gather(args))
    print(f"gyro bias [deg/s]  x {fit.bias_dps[0]:+.4f}  y {fit.bias_dps[1]:+.4f}  z {fit.bias_dps[2]:+.4f}"
          f"   (was {_fmt(previous.gyro_bias_dps, '+.4f')})")
    print(f"noise std [deg/s]  {_fmt(fit.std_dps, '.4f')}  over {fit.samples} still samples")
    return _store(args, previous.with_gyro(fit), how)


def cmd_mag(args) -> int:
    previous, how = _previous(args)
    fit = fit_magnetometer(gather(args), previous, args.method)
    report_mag(fit, previous)
    return _store(args, previous.with_mag(fit), how)


def cmd_mount(args) -> int:
    previous, how = _previous(args)
    drive = drive_calibration.read_drive(args.recording, args.unit, args.gnss)
    calibrated, _ = drive_calibration.measure_mount(drive, previous, args.lever_arm,
                                                    drive_calibration.Limits.of(args))
    return _store(args, calibrated, how)


def cmd_time(args) -> int:
    previous, how = _previous(args)
    drive = drive_calibration.read_drive(args.recording, args.unit, args.gnss)
    offset_s, report = drive_calibration.measure_time(drive, previous, args.lever_arm,
                                                      drive_calibration.Limits.of(args))
    return _store(args, previous.with_time_offset(offset_s, report), how)


def cmd_noise(args) -> int:
    previous, how = _previous(args)
    figures = noise_calibration.measure_noise([_parked_or_file(p) for p in args.recordings])
    print("\n".join(noise_calibration.report(figures)))
    if args.plot:
        print(f"Allan deviation drawn in {noise_calibration.write_plot(figures, args.plot)}")
    return _store(args, previous.with_noise(noise_calibration.noise_table(figures)), how)


def _parked_or_file(path: Path) -> Recording:
    """A CSV recording, or one of the car's shipped parked recordings by name (nocurrent, speed_0hz, ...)."""
    if not path.exists() and str(path) in PARKED:
        return load_parked(str(path))
    return load_recording(path)


COMMANDS = {"accel": cmd_accel, "gyro": cmd_gyro, "mag": cmd_mag, "mount": cmd_mount, "time": cmd_time,
            "noise": cmd_noise, "show": cmd_show, "record": cmd_record}


# -- fitting from a recording (also used by tests) -------------------------------------------
def _rate(rec: Recording) -> float:
    rate = rec.rate_hz
    return rate if math.isfinite(rate) and 5 < rate < 1000 else NOMINAL_RATE_HZ


def fit_accel(rec: Recording, previous: ImuCalibration, min_still_s: float = 1.0,
              max_std_g: float = 0.03) -> fitting.AccelFit:
    """Find the resting poses, average each in chip LSB, fit the six-position lines."""
    rate = _rate(rec)
    window = max(5, int(0.5 * rate))
    segments = fitting.still_segments(rec.accel_g, window, max_std_g, int(min_still_s * rate))
    pooled: dict[str, list[np.ndarray]] = {}
    for seg in segments:
        pose = fitting.classify_pose(rec.accel_g[seg].mean(axis=0))
        if pose:
            pooled.setdefault(pose, []).append(previous.accel_lsb(rec.accel_g[seg]))
    if not pooled:
        raise FitError(f"no resting pose of at least {min_still_s} s found in {len(rec)} frames")
    means = {p: np.concatenate(v).mean(axis=0) for p, v in pooled.items()}
    counts = {p: int(sum(len(x) for x in v)) for p, v in pooled.items()}
    return fitting.fit_six_position(means, counts)


def fit_gyro(rec: Recording, min_still_s: float = 2.0, max_std_dps: float = 0.5) -> fitting.GyroBiasFit:
    """The longest still period (gyro and accelerometer quiet) gives the bias."""
    rate = _rate(rec)
    both = np.hstack([rec.gyro_dps / max_std_dps, rec.accel_g / 0.03])
    segments = fitting.still_segments(both, max(5, int(0.5 * rate)), 1.0, int(min_still_s * rate))
    if not segments:
        raise FitError(f"no still period of at least {min_still_s} s in {len(rec)} frames")
    longest = max(segments, key=lambda s: s.stop - s.start)
    return fitting.fit_gyro_bias(rec.gyro_dps[longest], max_std_dps=max_std_dps)


def fit_magnetometer(rec: Recording, previous: ImuCalibration, method: str = "auto",
                     field_T: float = LISBON_FIELD_T,
                     inclination_deg: float = LISBON_INCLINATION_DEG) -> fitting.MagFit:
    """Drop the HMC5843's glitches (judged with the previous calibration), then fit.
    A fit must be at least a quarter of the local field's size (horizontal for 2-D)."""
    cal = SampleCalibrator(previous)
    glitches = MagGlitchFilter(field_T=field_T)
    keep = np.array([glitches.accept(m) for m in cal.mag_array(rec.mag_counts)], bool)
    if glitches.rejected:
        print(f"{glitches.rejected} magnetometer glitches left out of {len(rec)} frames")
    units = field_T / previous.tesla_per_mag_unit
    return fitting.fit_mag(rec.mag_counts[keep], method,
                           min_radius_2d=0.25 * units * math.cos(math.radians(inclination_deg)),
                           min_radius_3d=0.25 * units)


# -- reports --------------------------------------------------------------------------------
def _fmt(v, spec=".2f") -> str:
    return "[" + ", ".join(format(x, spec) for x in v) + "]"


def report_accel(fit: fitting.AccelFit, previous: ImuCalibration) -> None:
    print("pose   samples   residual [g] x, y, z")
    for pose in fitting.POSES:
        print(f"{pose:>4}  {fit.samples.get(pose, 0):8d}   {_fmt(fit.residual_g[pose], '+.4f')}")
    print("axis   gain [LSB/g]  (was)      offset [LSB]  (was)     rms residual [g]")
    for i, axis in enumerate("xyz"):
        print(f"  {axis}    {fit.gain_lsb_per_g[i]:9.2f}  ({previous.accel_gain_lsb_per_g[i]:7.2f})"
              f"   {fit.offset_lsb[i]:+9.2f}  ({previous.accel_offset_lsb[i]:+7.2f})"
              f"     {fit.rms_residual_g[i]:.4f}")


def report_mag(fit: fitting.MagFit, previous: ImuCalibration) -> None:
    unit_nt = previous.tesla_per_mag_unit * 1e9
    print(f"method {fit.method}")
    print(f"offset [nT]   {_fmt([o * unit_nt for o in fit.offset], '+.1f')}  "
          f"(units: {_fmt(fit.offset, '+.2f')})")
    if fit.ellipse is not None:
        print(f"alpha [deg]   {fit.info['alpha_deg']:.4f}")
        print(f"semi-minor/semi-major  {fit.info['axis_ratio']:.4f}")
        print("R_cal         " + "  ".join(_fmt(r, '+.4f') for r in fit.info["r_cal"]))
    print("C^-1          " + "  ".join(_fmt(r, '+.4f') for r in fit.c_inv))
    print(f"field after calibration {fit.radius * unit_nt / 1000:.2f} uT "
          f"({'horizontal' if fit.ellipse is not None else 'total'}), "
          f"rms spread {fit.rms_residual * unit_nt:.0f} nT")


def _previous(args) -> tuple[ImuCalibration, str]:
    firmware = args.firmware
    if firmware is None:
        stored = load_file(args.file).get(args.unit, {})
        firmware = stored.get("firmware", "viena") if isinstance(stored, dict) else "viena"
    return load_calibration(args.file, args.unit, firmware)


def _store(args, cal: ImuCalibration, how: str) -> int:
    if getattr(args, "dry_run", False):
        print("dry run: nothing stored")
        return 0
    save_calibration(args.file, args.unit, cal)
    print(f"stored in {args.file} [{args.unit}] (before: {how.split(': ', 1)[-1]})")
    return 0


# -- input ------------------------------------------------------------------------------------
def gather(args) -> Recording:
    given = sum(bool(x) for x in (args.recordings, args.port, args.live))
    if given != 1:
        raise ConfigError("give recordings, or --port URL, or --live (exactly one)")
    seconds = args.seconds or DEFAULT_SECONDS[args.command]
    if args.recordings:
        return joined([load_recording(p) for p in args.recordings])
    rec = from_port(args, seconds) if args.port else from_zenoh(args, seconds)
    if not len(rec):
        raise FitError("no frames arrived")
    if args.save_recording:
        save_recording(args.save_recording, rec)
    return rec


def from_port(args, seconds: float) -> Recording:
    from viena.services.imu.driver import DRIVERS

    firmware = args.firmware or "viena"
    readings = []
    print(f"reading {args.port} for {seconds:.0f} s ...", file=sys.stderr)
    with DRIVERS[firmware](args.port) as imu:
        end = clock.monotonic() + seconds
        while clock.monotonic() < end:
            r = imu.read(timeout=0.5)
            if r is not None:
                readings.append(r)
        print(f"{len(readings)} frames, decoder: {imu.stats}", file=sys.stderr)
    return from_readings(readings, args.port)


def from_zenoh(args, seconds: float) -> Recording:
    from viena.common.keys import Keys
    from viena.common.samples.imu import SAMPLE
    from viena.common.samples.topics import IMU_SAMPLE
    from viena.common.session import car_name, load_settings_file, open_session, zenoh_config

    toml = load_settings_file(args)
    key = Keys(car_name(args, toml)).of(IMU_SAMPLE, unit=args.unit)
    rows: list[tuple] = []
    lock, bad = threading.Lock(), [0]

    def on_sample(s) -> None:
        try:
            d = SAMPLE.decode(s.payload.to_bytes())
        except SampleError:
            bad[0] += 1
            return
        raw = d["raw"]
        with lock:
            rows.append((d["t"], d.get("board_id") or 0, raw["accel_g"], raw["gyro_dps"],
                         raw["mag_counts"], raw.get("euler_deg") or [math.nan] * 3))

    session = open_session(zenoh_config(args, toml))
    try:
        sub = session.declare_subscriber(key, on_sample)
        print(f"collecting {key} for {seconds:.0f} s ...", file=sys.stderr)
        clock.sleep(seconds)
        sub.undeclare()
    finally:
        session.close()
    if bad[0]:
        print(f"{bad[0]} malformed samples ignored", file=sys.stderr)
    with lock:
        taken = list(rows)

    def col(k: int) -> np.ndarray:
        return np.array([row[k] for row in taken], float).reshape(-1, 3)
    return Recording(np.array([row[0] for row in taken], np.int64), np.array([row[1] for row in taken], int),
                     col(2), col(3), col(4), col(5), name=key)
