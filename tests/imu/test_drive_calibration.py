"""`viena calibrate imu mount|time` on drives as real ones are (issue 25): any fix rate from
1 to 20 Hz, a stop on a slope, a clock seconds off, either command first, results too
unsure to store, and recordings that cannot give a figure, each refused with its reason.

The drives are the simulated car's, offline (benchmarks/simdrive.py): the Razor twin's
board with its own errors screwed in at a known rotation, the NovAtel twin's fixes, both
through the services' sample code, written to MCAP as `viena record` does. The twin's
accelerometer has a bias and misaligned axes of its own, drawn per run; they lean the level
it reads by up to half a degree, which no drive can tell from the mount. So the mount is
judged against the accelerometer's own (`accelerometer_mount`: the nominal mount levelled as
the board reads gravity parked at the start, whose slope is known), within 0.5 deg, and
against the nominal mount within the uncertainty the tool states. Clock within 20 ms."""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pymap3d
import pytest

from benchmarks.simdrive import Drive, DriveSamples
from viena.common.recording import RecordingWriter
from viena.common.samples.fix import FIX
from viena.common.samples.imu import SAMPLE
from viena.services.imu import drive_calibration
from viena.services.imu.calibration_cli import main as calibrate
from viena.services.imu.calibration_file import load_calibration
from viena.services.imu.model.calibration import seed_calibration
from viena.services.imu.model.fitting import FitError, block_weights
from viena.services.imu.model.motion import gnss_motion
from viena.services.imu.model.mount import Mount, Stop, facing_both_ways, levelling, wahba
from viena.services.imu.simulator import RazorBoard
from viena.services.sim.model.car import CarParams

LEVER_ARM_M = (0.0, 1.0, 1.5)                       # simdrive's antenna, from the rear axle
LEVER_ARM = tuple(str(x) for x in LEVER_ARM_M)
IMU_KEY, FIX_KEY = "viena/elettra/imu/razor0/sample", "viena/elettra/gnss/gnss0/fix"
MOUNT = (-93.5, 4.2, -2.7)                           # an axis swap plus a few degrees
LATE_S = 0.1


# -- drives --------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimDrive:
    imu: tuple                     # viena.imu.sample/1 dicts
    fixes: tuple                   # viena.gnss.fix/1 dicts
    accel_matrix: np.ndarray       # the twin's accelerometer this run: board reading = A (board truth)


@functools.lru_cache(maxsize=8)
def sim_drive(mount=MOUNT, rate_hz: float = 20.0, seconds: float = 180.0, seed: int = 1,
              stop_slope_pct: float = 0.0, velocity: bool = True, cep_m: float | None = None,
              route: str = "campus") -> SimDrive:
    """A simulated drive: parked 10 s, then the campus loop at 3-5 m/s (or the open oval).
    `stop_slope_pct`: parked on that slope, and hills of that grade after."""
    drive = Drive(duration_s=seconds, seed=seed, gnss_rate_hz=rate_hz, grade_pct=stop_slope_pct,
                  gnss_velocity=velocity, route=route,
                  car=CarParams(lookahead_m=12.0) if route == "open" else CarParams())
    samples = DriveSamples(drive)
    if stop_slope_pct:
        samples.hills.s = drive.grade_period_m / 4                # where the grade is steepest
    if cep_m is not None:
        samples.sensors.solver.errors.set_cep(cep_m)
    board = samples.sensors.board = RazorBoard(mount_zyx_deg=mount)
    imu, fixes = [], []
    for kind, sample, _ in samples:
        (imu if kind == "imu" else fixes).append(sample)
    return SimDrive(tuple(imu), tuple(fixes), board.run(samples.rng).errors.accel_matrix)


def record(path, drive: SimDrive, imu_shift_s: float = LATE_S, fixes=None):
    """An MCAP recording of the drive (or its IMU with other `fixes`); IMU stamps moved by
    `imu_shift_s` (a late clock)."""
    writer = RecordingWriter(path)
    shift = int(round(imu_shift_s * 1e9))
    items = [(s["t"] + shift, IMU_KEY, SAMPLE, {**s, "t": s["t"] + shift}) for s in drive.imu]
    items += [(f["t"], FIX_KEY, FIX, f) for f in (drive.fixes if fixes is None else fixes)]
    for t, key, schema, value in sorted(items, key=lambda i: i[0]):
        writer.write(key, f"application/msgpack;{schema.name}", t, schema.encode(value))
    return writer.close()


def drive_data(drive: SimDrive, imu_shift_s: float = LATE_S) -> drive_calibration.DriveData:
    imu = drive.imu
    return drive_calibration.DriveData(np.array([s["t"] for s in imu]) * 1e-9 + imu_shift_s,
                                       np.array([s["raw"]["accel_g"] for s in imu]),
                                       np.array([s["raw"]["gyro_dps"] for s in imu]), list(drive.fixes), "gnss0")


def accelerometer_mount(mount, drive: SimDrive, stop_slope_pct: float = 0.0, parked_s: float = 8.0) -> Mount:
    """The mount the twin's accelerometer has: the nominal one with its axes' misalignment
    (the rotation part of the inverse of this run's I + S + M), levelled as it reads gravity
    parked at the start on a known slope (its bias and misalignment lean that reading)."""
    nominal = Mount(tuple(mount)).matrix
    u, _, vt = np.linalg.svd(np.linalg.inv(drive.accel_matrix))
    turned = nominal @ (u @ vt)
    parked = np.array([s["raw"]["accel_g"] for s in drive.imu if s["t"] - drive.imu[0]["t"] < parked_s * 1e9])
    pitch = math.atan(stop_slope_pct / 100.0)
    up_on_slope = np.array([0.0, math.sin(pitch), math.cos(pitch)])
    return Mount.of_matrix(_between(turned @ parked.mean(axis=0), up_on_slope) @ turned)


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction a onto direction b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(a @ b)
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def run(tmp_path, command: str, path, *extra: str) -> tuple[int, object]:
    cal_file = tmp_path / "cal.toml"
    code = calibrate([command, str(path), "--unit", "razor0", "--file", str(cal_file), "--lever-arm", *LEVER_ARM,
                      *extra])
    return code, (load_calibration(cal_file, "razor0")[0] if cal_file.exists() else None)


# -- the GNSS side at any fix rate -----------------------------------------------------------
def circle_fixes(rate_hz: float, speed_mps: float = 5.0, radius_m: float = 20.0, seconds: float = 30.0,
                 accel_mps2: float = 0.0) -> list[dict]:
    """Fixes of an antenna going round a circle, speeding up at accel_mps2."""
    lat0, lon0 = 38.737, -9.139
    out = []
    for k in range(int(seconds * rate_hz)):
        t = k / rate_hz
        v = speed_mps + accel_mps2 * t
        angle = (speed_mps * t + 0.5 * accel_mps2 * t * t) / radius_m
        e, n = radius_m * math.sin(angle), radius_m * (1 - math.cos(angle))
        ve, vn = v * math.cos(angle), v * math.sin(angle)
        ecef = pymap3d.enu2ecef(e, n, 0.0, lat0, lon0, 0.0)
        vel = pymap3d.enu2uvw(ve, vn, 0.0, lat0, lon0)
        out.append({"t": 1_717_236_000_000_000_000 + int(t * 1e9), "unit": "gnss0", "valid": True,
                    "pos_status": "SOL_COMPUTED", "ecef_m": [float(x) for x in ecef], "ecef_sigma_m": [0.01] * 3,
                    "vel_ecef_mps": [float(x) for x in vel], "vel_sigma_mps": [0.01] * 3,
                    "vel_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY", "vel_latency_s": 0.0})
    return out


@pytest.mark.parametrize("rate_hz", [1.0, 2.0, 4.0, 5.0, 10.0, 20.0])
def test_turn_rate_and_acceleration_come_from_fixes_at_any_rate(rate_hz):
    """Fixes 0.2 s or more apart used to find no neighbour within the derivative's 0.3 s
    window, and every turn rate and acceleration came out zero."""
    motion = gnss_motion(circle_fixes(rate_hz, accel_mps2=0.2))
    inner = slice(2, -2)
    expected = (5.0 + 0.2 * (motion.t_s - motion.t_s[0])) / 20.0
    assert motion.yaw_rate_radps[inner] == pytest.approx(expected[inner], rel=0.02)
    assert motion.forward_accel_mps2[inner] == pytest.approx(0.2, abs=0.01)


def test_a_receiver_without_velocity_gets_it_from_its_positions():
    with_velocity = circle_fixes(4.0)
    positions_only = [{**f, "vel_ecef_mps": None, "vel_status": "INSUFFICIENT_OBS", "vel_type": "NONE"}
                      for f in with_velocity]
    motion = gnss_motion(positions_only)
    assert motion.from_positions
    assert motion.speed_mps[1:-1] == pytest.approx(5.0, rel=0.01)      # the chord of a 1/16 turn
    assert motion.yaw_rate_radps[2:-2] == pytest.approx(0.25, rel=0.02)


# -- the tools on whole drives -------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("rate_hz", [1.0, 4.0, 5.0, 10.0, 20.0])
def test_mount_and_clock_at_any_fix_rate(tmp_path, rate_hz):
    """Before: refused at 1-5 Hz ("neither turns nor speed changes"); now within 0.5 deg
    and 20 ms. `mount` stores the clock it timed the board by, too. Below 10 Hz three
    minutes of the slow campus loop leave the mount about as sure as the 0.5 deg asked (at 4
    Hz once just refused, +- 0.50 deg): eight minutes, the length of the drive the issue was
    measured on; at 1 Hz eight minutes once left it 0.56 deg off (within its +- 0.48): twelve."""
    drive = sim_drive(rate_hz=rate_hz, seconds=720.0 if rate_hz < 2 else 480.0 if rate_hz < 10 else 180.0)
    path = record(tmp_path / "drive.mcap", drive)
    code, cal = run(tmp_path, "mount", path)
    assert code == 0
    assert accelerometer_mount(MOUNT, drive).angle_to_deg(cal.mount) < 0.5, cal.mount
    assert Mount(MOUNT).angle_to_deg(cal.mount) < 2.5 * cal.info["mount"]["sigma_deg"]
    assert cal.time_offset_s == pytest.approx(-LATE_S, abs=0.020)
    assert cal.info["timing"]["sigma_s"] < 0.020
    code, cal = run(tmp_path, "time", path)
    assert code == 0
    assert cal.time_offset_s == pytest.approx(-LATE_S, abs=0.020)


@pytest.mark.slow
def test_a_stop_on_a_slope_does_not_tilt_the_mount(tmp_path, capsys):
    """Parked on an 8 % slope (4.6 deg), then hills of that grade: the level comes from the
    drive (the road's slope from the GNSS's climb), and the stop's slope is reported.
    Before: refused ("only 9 samples parked"), or 5.76 deg off on the real drive."""
    drive = sim_drive(stop_slope_pct=8.0)
    code, cal = run(tmp_path, "mount", record(tmp_path / "drive.mcap", drive))
    assert code == 0
    assert accelerometer_mount(MOUNT, drive, stop_slope_pct=8.0).angle_to_deg(cal.mount) < 0.5, cal.mount
    stop = next(line for line in capsys.readouterr().out.splitlines() if "parked 0-" in line)
    slope = float(stop.split("slope ")[1].split(" deg")[0])
    assert slope == pytest.approx(4.6, abs=0.6), stop


@pytest.mark.slow
def test_a_clock_seconds_off_is_found(tmp_path):
    """3.25 s late, as the issue's real drive: before, clipped to 1 s with no warning."""
    drive = sim_drive()
    code, cal = run(tmp_path, "time", record(tmp_path / "drive.mcap", drive, imu_shift_s=3.25))
    assert code == 0
    assert cal.time_offset_s == pytest.approx(-3.25, abs=0.020)


@pytest.mark.slow
def test_a_clock_beyond_the_search_is_refused_not_clipped(tmp_path, capsys):
    drive = sim_drive()
    code, cal = run(tmp_path, "time", record(tmp_path / "drive.mcap", drive, imu_shift_s=-6.0))
    assert code == 1 and cal is None
    assert "edge of the +-5.0 s search" in capsys.readouterr().err
    wider = drive_calibration.Limits(max_offset_s=8.0)
    found = drive_calibration.time_drive(drive_data(drive, -6.0), seed_calibration(), LEVER_ARM_M, wider)
    assert found.timing.offset_s == pytest.approx(6.0, abs=0.020)


@pytest.mark.slow
def test_time_first_or_mount_first_agree(tmp_path):
    """A board upside down, a minute of driving: `time` before `mount` used to read the
    yaw rate off the stored (identity) mount, upside down, and was 230 ms off. Now both
    work in the board's own axes and either may come first."""
    mount = (6.0, 2.0, 180.0)
    drive = sim_drive(mount=mount, seconds=75.0)
    path = record(tmp_path / "drive.mcap", drive)
    code, cal = run(tmp_path, "time", path)
    assert code == 0
    assert cal.time_offset_s == pytest.approx(-LATE_S, abs=0.020)
    first = cal.time_offset_s
    code, cal = run(tmp_path, "mount", path)        # the same recording: its offset replaced, not added to
    assert code == 0
    assert accelerometer_mount(mount, drive).angle_to_deg(cal.mount) < 0.5, cal.mount
    assert cal.time_offset_s == pytest.approx(first, abs=0.005)


@pytest.mark.slow
def test_a_result_less_sure_than_the_limit_is_not_stored(tmp_path, capsys):
    """Half a minute of driving with 1 Hz fixes: the mount's uncertainty is above 0.5 deg,
    so nothing is stored and the reason is given."""
    drive = sim_drive(rate_hz=1.0, seconds=45.0)
    code, cal = run(tmp_path, "mount", record(tmp_path / "drive.mcap", drive))
    assert code == 1 and cal is None
    err = capsys.readouterr().err
    assert "more than --max-sigma-deg 0.5" in err, err
    strict = drive_calibration.Limits(max_sigma_ms=0.5)
    with pytest.raises(FitError, match="more than --max-sigma-ms 0.5"):
        drive_calibration.measure_time(drive_data(sim_drive()), seed_calibration(), LEVER_ARM_M, strict)


@pytest.mark.slow
def test_samples_of_another_drive_are_refused(tmp_path, capsys):
    drive, other = sim_drive(seconds=75.0), sim_drive(seconds=75.0, route="open")
    code, cal = run(tmp_path, "time", record(tmp_path / "drive.mcap", drive, fixes=other.fixes))
    assert code == 1 and cal is None
    assert "does not match the GNSS" in capsys.readouterr().err


@pytest.mark.slow
def test_positions_only_fixes_of_rtk_grade_are_enough(tmp_path):
    """A receiver without velocity (NMEA GGA, a NovAtel without BESTVEL) at centimetre
    level: velocities from its positions."""
    drive = sim_drive(rate_hz=10.0, velocity=False, cep_m=0.02)
    code, cal = run(tmp_path, "mount", record(tmp_path / "drive.mcap", drive))
    assert code == 0
    assert accelerometer_mount(MOUNT, drive).angle_to_deg(cal.mount) < 0.5, cal.mount
    assert cal.time_offset_s == pytest.approx(-LATE_S, abs=0.020)


@pytest.mark.slow
def test_positions_only_fixes_of_standalone_grade_are_refused(tmp_path, capsys):
    drive = sim_drive(rate_hz=10.0, velocity=False)
    code, cal = run(tmp_path, "mount", record(tmp_path / "drive.mcap", drive))
    assert code == 1 and cal is None
    assert "uncertain by" in capsys.readouterr().err


# -- pieces ----------------------------------------------------------------------------------
def _stop(up, heading_deg, place=(0.0, 0.0, 0.0)) -> Stop:
    return Stop(0.0, 10.0, 800, np.asarray(up, float) / np.linalg.norm(up), np.zeros(3), np.asarray(place, float),
                math.radians(heading_deg))


def test_two_stops_at_one_place_facing_both_ways_are_found():
    slope = math.radians(4.0)
    up = (0.0, math.sin(slope), math.cos(slope))
    down = (0.0, -math.sin(slope), math.cos(slope))
    uphill, downhill = _stop(up, 10.0), _stop(down, 185.0, place=(2.0, 1.0, 0.0))
    elsewhere, same_way = _stop(down, 190.0, place=(50.0, 0.0, 0.0)), _stop(up, 15.0)
    assert facing_both_ways([uphill, elsewhere, same_way]) is None
    pair = facing_both_ways([uphill, elsewhere, downhill])
    assert pair is not None and {id(s) for s in pair} == {id(uphill), id(downhill)}
    level = levelling(np.add(pair[0].up_board, pair[1].up_board))
    assert level == pytest.approx(np.eye(3), abs=1e-9)


def test_wahba_recovers_a_rotation_and_the_bootstrap_keeps_blocks_together():
    rng = np.random.default_rng(3)
    truth = Mount((-93.5, 4.2, -2.7)).matrix
    u = rng.normal(size=(200, 3))
    assert wahba(np.einsum("ki,kj->ij", u @ truth.T, u)) == pytest.approx(truth, abs=1e-12)
    t = np.arange(0.0, 100.0, 0.5)
    (weights,), blocks = block_weights([t], 10.0, replicates=50)
    assert blocks == 10 and weights.shape == (50, 200)
    assert np.all(weights.sum(axis=1) == 200)                         # as many blocks drawn as there are
    assert np.all(weights[:, :20] == weights[:, :1])                  # a block's points go together
