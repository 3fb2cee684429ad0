"""The IMU's mount and clock, measured from a recorded drive by `viena calibrate imu mount|time`.

The drives are the simulated car's, offline: the Razor twin's board model screwed into the
car at a known rotation (an axis swap plus a few degrees), the NovAtel twin's fixes, both
through the services' own sample code, written to an MCAP file as `viena record` does.
The measured mount must come within 0.5 deg of the accelerometer's own mount (the twin's
accelerometer has a bias and misaligned axes that lean the level it reads by up to half a
degree, which no drive tells from the mount: test_drive_calibration.accelerometer_mount)
and within its stated uncertainty of the true one; the measured clock offset within 20 ms."""
from __future__ import annotations

import numpy as np
import pytest
from test_drive_calibration import accelerometer_mount, sim_drive

from benchmarks.imu import LEVER_ARM_M
from benchmarks.imu import mounted_drive as drive
from benchmarks.simdrive import Drive, DriveSamples
from viena.common.recording import RecordingWriter
from viena.common.samples.fix import FIX
from viena.common.samples.imu import SAMPLE
from viena.services.imu.calibration_cli import main as calibrate
from viena.services.imu.calibration_file import load_calibration
from viena.services.imu.driver import Frame, Reading
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.model.mount import Mount
from viena.services.imu.simulator import RazorBoard

pytestmark = pytest.mark.slow
LEVER_ARM = tuple(str(x) for x in LEVER_ARM_M)      # simdrive's antenna, from the rear axle
IMU_KEY, FIX_KEY = "viena/elettra/imu/razor0/sample", "viena/elettra/gnss/gnss0/fix"


def record(path, imu, fixes, imu_shift_s: float = 0.0):
    """An MCAP recording of the drive; IMU stamps moved by `imu_shift_s` (a late clock)."""
    writer = RecordingWriter(path)
    shift = int(round(imu_shift_s * 1e9))
    items = [(s["t"] + shift, IMU_KEY, SAMPLE, {**s, "t": s["t"] + shift}) for s in imu]
    items += [(f["t"], FIX_KEY, FIX, f) for f in fixes]
    for t, key, schema, value in sorted(items, key=lambda i: i[0]):
        writer.write(key, f"application/msgpack;{schema.name}", t, schema.encode(value))
    return writer.close()


@pytest.fixture(scope="module")
def level_drive():
    return drive()


@pytest.mark.parametrize("late_s", [-0.5, -0.2, -0.05, 0.05, 0.2, 0.5])
def test_the_clock_offset_is_measured_within_20_ms(tmp_path, level_drive, late_s):
    imu, fixes = level_drive
    path = record(tmp_path / "drive.mcap", imu, fixes, imu_shift_s=late_s)
    cal_file = tmp_path / "cal.toml"
    assert calibrate(["time", str(path), "--unit", "razor0", "--file", str(cal_file),
                      "--lever-arm", *LEVER_ARM]) == 0
    cal, _ = load_calibration(cal_file, "razor0")
    # stamps late by late_s: the correction is -late_s (the twin's own integration lag aside)
    assert cal.time_offset_s == pytest.approx(-late_s, abs=0.020)
    assert cal.info["timing"]["sigma_s"] < 0.020


@pytest.mark.parametrize("mount, seed", [((90.0, 0.0, 0.0), 7), ((-93.5, 4.2, -2.7), 1),
                                         ((178.0, -3.0, 5.5), 2), ((6.0, 2.0, 180.0), 6)])
def test_the_mount_is_measured_within_half_a_degree(tmp_path, mount, seed):
    """Three minutes: parked 10 s, then the loop at 3-5 m/s."""
    sim = sim_drive(mount=mount, seed=seed)
    path = record(tmp_path / "drive.mcap", sim.imu, sim.fixes, imu_shift_s=0.1)   # and a late clock
    cal_file = tmp_path / "cal.toml"
    assert calibrate(["mount", str(path), "--unit", "razor0", "--file", str(cal_file),
                      "--lever-arm", *LEVER_ARM]) == 0
    cal, _ = load_calibration(cal_file, "razor0")
    assert accelerometer_mount(mount, sim).angle_to_deg(cal.mount) < 0.5, cal.mount
    assert Mount(mount).angle_to_deg(cal.mount) < 2.5 * cal.info["mount"]["sigma_deg"], cal.mount


def test_a_mounted_board_publishes_in_the_body_frame():
    """The service's calibrator with the unit's mount undoes the board's rotation."""
    rng = np.random.default_rng(1)
    mount = (6.0, 2.0, 180.0)                           # upside down, a little askew
    board = RazorBoard(mount_zyx_deg=mount)
    samples = DriveSamples(Drive(duration_s=12.0, seed=2))
    truth = next(t for kind, _, t in samples if kind == "imu")
    m = board.measure(truth, rng)
    frame = Frame(1, m.accel_g, m.gyro_dps, m.mag_counts, m.euler_deg)
    cal = seed_calibration().with_mount(Mount(mount), {})
    accel = SampleCalibrator(cal).accel(Reading(0, 0, 1, frame).frame.accel_g)
    assert accel == pytest.approx(truth.specific_force_body_mps2, abs=0.1)       # +g on z
    tilted = SampleCalibrator(seed_calibration()).accel(frame.accel_g)
    assert tilted[2] < -9.0                                                       # not without it


def test_the_stamps_carry_the_units_offset():
    cal = SampleCalibrator(seed_calibration().with_time_offset(-0.15, {}))
    assert cal.time_ns(1_000_000_000) == 850_000_000


def test_a_drive_without_parking_or_turns_is_refused_with_the_reason(tmp_path):
    imu, fixes = drive(seconds=9.0)                   # still parked the whole time
    path = record(tmp_path / "drive.mcap", imu, fixes)
    cal_file = tmp_path / "cal.toml"
    assert calibrate(["mount", str(path), "--unit", "razor0", "--file", str(cal_file)]) == 1
    assert not cal_file.exists()
