"""Calibration: the default magnetometer calibration (docs/sensors.md#default-calibration)
reproduced, known distortions recovered from twin data, fits that cannot be made refused, and the
TOML file the service loads. "Seed" and "table 5.x" in names: docs/README.md#glossary."""
from __future__ import annotations

import math

import numpy as np
import pytest

from viena.common.errors import ConfigError
from viena.services.imu.calibration_cli import fit_accel, fit_gyro, fit_magnetometer, main
from viena.services.imu.calibration_file import load_calibration, save_calibration
from viena.services.imu.model import fitting
from viena.services.imu.model.calibration import (
    HMC5843_TESLA_PER_COUNT,
    ImuCalibration,
    SampleCalibrator,
    seed_calibration,
)
from viena.services.imu.model.fitting import FitError
from viena.services.imu.recordings import save_recording
from viena.services.imu.simulator import NO_ERRORS, RazorBoard, RazorTwin
from viena.services.imu.simulator.scenarios import record_twin, six_poses, still, tumbling, turning

# the default magnetometer calibration as the guide prints it (docs/sensors.md#default-calibration)
TABLE_R_CAL = [[-0.3011, -0.9536, 0], [0.9536, -0.3011, 0], [0, 0, 1]]
TABLE_C_INV = [[0.9961, 0.0124, 0], [0.0124, 0.9606, 0], [0, 0, 1]]
# a board unlike the default one, so recovering it means something
ODD_BOARD = dict(accel_gain_lsb_per_g=(250.0, 262.0, 245.0), accel_offset_lsb=(-8.0, 5.0, 20.0),
                 eeprom_gain_lsb_per_g=(256.0,) * 3, eeprom_offset_lsb=(0.0,) * 3,
                 gyro_bias_dps=(0.3, -0.2, 0.1))
NOMINAL_EEPROM = ImuCalibration(eeprom_gain_lsb_per_g=(256.0,) * 3, eeprom_offset_lsb=(0.0,) * 3)


def twin(seed: int, **board) -> RazorTwin:
    """A board whose chips are exactly as declared: without the twin's per-run draws (turn-on
    bias, scale factor, misalignment: docs/sensors.md#imu-error-model), which a fit takes in
    as part of what it measures, as it would on the car."""
    return RazorTwin(None, RazorBoard(**{"errors": NO_ERRORS, **board}), boot_s=0.1, seed=seed)


# -- the default calibration's figures (docs/sensors.md#default-calibration) ---------------------
def test_seed_c_inv_and_r_cal_are_table_5_4():
    alpha = math.radians(107.5238)
    assert np.allclose(fitting.rotation_z(alpha), TABLE_R_CAL, atol=6e-5)
    assert np.allclose(fitting.ellipse_c_inv(alpha, 0.9567), TABLE_C_INV, atol=6e-5)
    seed = seed_calibration()
    assert np.allclose(seed.mag_c_inv, TABLE_C_INV, atol=6e-5)
    offset_nT = np.array(seed.mag_offset) * HMC5843_TESLA_PER_COUNT * 1e9
    assert np.allclose(offset_nT, [-25828, -21703, 0])
    assert seed.accel_gain_lsb_per_g == (266.04, 266.27, 253.66)          # default accel gain, x y z
    assert seed.accel_offset_lsb == (13.83, -3.18, -3.47)


def test_the_2d_method_reproduces_table_5_4_from_data_built_with_it():
    """Field points of a car turning in Lisbon, distorted by the default calibration's offset, alpha and
    axis ratio; the fit gives back those and the printed R_cal and C^-1."""
    c = np.linalg.inv(fitting.ellipse_c_inv(math.radians(107.5238), 0.9567))
    heading = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    horizontal = 26503.5                                   # nT, |[-1121.5, 26479.8]|
    h = np.column_stack([horizontal * np.cos(heading), horizontal * np.sin(heading),
                         np.full_like(heading, -34884.7)])
    sensed = h @ c.T + [-25828.0, -21703.0, 0.0]
    fit = fitting.fit_mag_ellipse(sensed)
    assert fit.offset[0] == pytest.approx(-25828.0, abs=0.5)
    assert fit.offset[1] == pytest.approx(-21703.0, abs=0.5)
    assert fit.info["alpha_deg"] == pytest.approx(107.5238, abs=1e-3)
    assert fit.info["axis_ratio"] == pytest.approx(0.9567, abs=1e-5)
    assert np.allclose(fit.info["r_cal"], TABLE_R_CAL, atol=6e-5)
    assert np.allclose(fit.c_inv, TABLE_C_INV, atol=6e-5)
    corrected = (sensed - fit.offset) @ np.array(fit.c_inv).T
    radius = np.hypot(corrected[:, 0], corrected[:, 1])
    assert radius.std() / radius.mean() < 1e-4             # a circle again


# -- recovering a known board from twin data ---------------------------------------------------
def test_six_position_fit_recovers_gains_and_offsets():
    rec = record_twin(twin(1, **ODD_BOARD), six_poses())
    fit = fit_accel(rec, NOMINAL_EEPROM)
    assert set(fit.samples) == set(fitting.POSES)
    assert np.allclose(fit.gain_lsb_per_g, ODD_BOARD["accel_gain_lsb_per_g"], rtol=3e-3)
    assert np.allclose(fit.offset_lsb, ODD_BOARD["accel_offset_lsb"], atol=1.5)
    assert max(fit.rms_residual_g) < 0.01
    cal = SampleCalibrator(NOMINAL_EEPROM.with_accel(fit))
    level = record_twin(twin(5, **ODD_BOARD), still(3, yaw=1.0))
    a = cal.accel_array(level.accel_g).mean(axis=0)
    assert np.allclose(a, [0, 0, 9.8006], atol=0.03)


def test_the_seed_board_with_its_eeprom_needs_no_correction():
    rec = record_twin(twin(2), six_poses(hold_s=2.0))
    fit = fit_accel(rec, seed_calibration())
    assert np.allclose(fit.gain_lsb_per_g, (266.04, 266.27, 253.66), rtol=3e-3)
    assert np.allclose(fit.offset_lsb, (13.83, -3.18, -3.47), atol=1.5)


def test_gyro_bias_from_a_still_period():
    rec = record_twin(twin(3, **ODD_BOARD), still(8))
    fit = fit_gyro(rec)
    assert np.allclose(fit.bias_dps, ODD_BOARD["gyro_bias_dps"], atol=0.01)
    assert fit.samples > 500


def test_2d_hard_and_soft_iron_recovered_from_a_drive_in_circles():
    board = dict(mag_offset_counts=(120.0, -80.0, 0.0),
                 mag_c=tuple(map(tuple, np.linalg.inv(fitting.ellipse_c_inv(math.radians(30), 0.85)))))
    rec = record_twin(twin(4, **board), turning(turns=1.5, period_s=16))
    fit = fit_magnetometer(rec, seed_calibration())
    assert fit.method == "ellipse-2d"
    assert np.allclose(fit.offset, (120, -80, 0), atol=1.5)
    assert fit.info["alpha_deg"] == pytest.approx(30, abs=1.0)
    assert fit.info["axis_ratio"] == pytest.approx(0.85, abs=0.005)
    # calibrated, the horizontal field has one size whatever the heading
    cal = SampleCalibrator(seed_calibration().with_mag(fit))
    h = cal.mag_array(rec.mag_counts)
    horizontal = np.hypot(h[:, 0], h[:, 1])
    assert horizontal.std() / horizontal.mean() < 0.02


def test_3d_ellipsoid_recovered_when_the_data_span_3d():
    c = np.array([[1.1, 0.05, 0.02], [0.05, 0.92, -0.03], [0.02, -0.03, 1.0]])
    board = dict(mag_offset_counts=(60.0, -150.0, 40.0), mag_c=tuple(map(tuple, c)))
    rec = record_twin(twin(6, **board), tumbling(seconds=50))
    fit = fit_magnetometer(rec, seed_calibration())
    assert fit.method == "ellipsoid-3d"
    assert np.allclose(fit.offset, (60, -150, 40), atol=2.0)
    product = np.array(fit.c_inv) @ c                         # a multiple of the identity
    assert np.allclose(product / product[0, 0], np.eye(3), atol=0.01)
    h = SampleCalibrator(seed_calibration().with_mag(fit)).mag_array(rec.mag_counts)
    size = np.linalg.norm(h, axis=1)
    assert size.std() / size.mean() < 0.02


# -- refusals ---------------------------------------------------------------------------------------
def test_fits_that_cannot_be_made_say_why():
    with pytest.raises(FitError, match="missing"):
        fitting.fit_six_position({"+z": np.zeros(3), "-z": np.zeros(3)})
    with pytest.raises(FitError, match="at least 20 points"):
        fitting.fit_ellipse(np.arange(5.0), np.arange(5.0))
    with pytest.raises(FitError, match="collinear|ellipse"):
        fitting.fit_ellipse(np.linspace(0, 1, 50), np.linspace(0, 2, 50))
    arc = np.linspace(0, 1.0, 60)                             # 57 degrees of a circle
    with pytest.raises(FitError, match="cover only"):
        fitting.fit_ellipse(300 * np.cos(arc), 300 * np.sin(arc))
    with pytest.raises(FitError, match="not still"):
        fitting.fit_gyro_bias(np.random.default_rng(0).normal(0, 3, (200, 3)))
    with pytest.raises(FitError, match="do not span 3-D"):
        fitting.fit_mag_ellipsoid(np.column_stack([np.random.default_rng(0).normal(0, 300, (200, 2)),
                                                   np.zeros(200)]))


def test_a_parked_car_is_not_a_magnetometer_calibration():
    rec = record_twin(twin(7), still(5))
    with pytest.raises(FitError, match="did the car turn"):
        fit_magnetometer(rec, seed_calibration())


def test_a_failed_fit_keeps_the_stored_calibration(tmp_path, capsys):
    path = tmp_path / "cal.toml"
    poses = tmp_path / "poses.csv"
    save_recording(poses, record_twin(twin(8, **ODD_BOARD), six_poses(hold_s=2.0)))
    # the stored calibration must describe the same EEPROM the frames went through
    save_calibration(path, "razor0", NOMINAL_EEPROM)
    assert main(["accel", str(poses), "--file", str(path)]) == 0
    stored = path.read_bytes()
    cal, how = load_calibration(path, "razor0")
    assert np.allclose(cal.accel_gain_lsb_per_g, ODD_BOARD["accel_gain_lsb_per_g"], rtol=3e-3)
    assert "calibration from" in how
    parked = tmp_path / "parked.csv"
    save_recording(parked, record_twin(twin(9), still(3)))
    assert main(["mag", str(parked), "--file", str(path)]) == 1
    assert main(["accel", str(parked), "--file", str(path)]) == 1
    assert "calibration not changed" in capsys.readouterr().err
    assert path.read_bytes() == stored
    assert main(["show", "--file", str(path)]) == 0
    assert "gain_lsb_per_g = [2" in capsys.readouterr().out


# -- the file ------------------------------------------------------------------------------------------
def test_missing_file_or_unit_means_the_seed_and_the_log_says_so(tmp_path):
    cal, how = load_calibration(tmp_path / "none.toml", "razor0")
    assert cal == seed_calibration() and "no such file" in how and "seed" in how
    save_calibration(tmp_path / "cal.toml", "razor1", seed_calibration())
    cal, how = load_calibration(tmp_path / "cal.toml", "razor0")
    assert cal == seed_calibration() and "no [razor0] table" in how


def test_toml_round_trip_keeps_other_units(tmp_path):
    path = tmp_path / "cal.toml"
    a = seed_calibration().__class__(gyro_bias_dps=(0.1, -0.2, 0.3), mag_method="ellipse-2d",
                                     info={"mag": {"alpha_deg": 107.5, "radius": 345.0}})
    save_calibration(path, "razor0", a)
    save_calibration(path, "razor1", seed_calibration("razor-ahrs"))
    back, _ = load_calibration(path, "razor0")
    assert back.gyro_bias_dps == (0.1, -0.2, 0.3) and back.mag_c_inv == a.mag_c_inv
    assert back.info["mag"]["alpha_deg"] == 107.5
    other, _ = load_calibration(path, "razor1", "razor-ahrs")
    assert other == seed_calibration("razor-ahrs")
    assert "bias_dps = [0.1, -0.2, 0.3]" in path.read_text()


@pytest.mark.parametrize("text, message", [
    ("[razor0\n", "razor0|Expected|line"),
    ("[razor0.mag]\nc_inv = [[1, 0, 0], [0, 0, 0], [0, 0, 1]]\n", "invertible"),
    ("[razor0.accel]\ngain_lsb_per_g = [266.0, -1.0, 250.0]\n", "positive"),
    ("[razor0.gyro]\nbias_dps = [0.0, 0.0]\n", "three finite"),
    ("[razor0]\nfirmware = \"razor-ahrs\"\n", "runs 'viena'"),
])
def test_a_broken_file_is_a_config_error_naming_it(tmp_path, text, message):
    path = tmp_path / "cal.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_calibration(path, "razor0", "viena")


def test_shipped_seed_file_matches_the_code():
    from viena.services.imu.recordings import DATA_DIR
    cal, _ = load_calibration(DATA_DIR / "calibration_seed.toml", "razor0")
    assert cal == seed_calibration()
