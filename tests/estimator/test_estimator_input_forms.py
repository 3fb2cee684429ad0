"""What the estimator accepts beyond the NovAtel's own fixes (issue 13, item 5): sigmas along
ENU or as horizontal/vertical, numpy numbers, receivers that send no velocity (NMEA GGA),
a receiver's velocity latency as a setting, and standstill thresholds that fit the IMU and
the car (learnt from the first seconds parked, or set)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from estimator_helpers import generate, settings_for

from benchmarks.simdrive import Drive
from viena.common.rotation import wrap_angle
from viena.common.samples.fix import read_fix
from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.standstill import ACCEL_FLOOR_MPS2, GYRO_FLOOR_RADPS

DRIVE = Drive(duration_s=25.0, seed=11)


@pytest.fixture(scope="module")
def drive():
    samples, origin = generate(DRIVE)
    return samples, origin


def feed(samples, origin, change=lambda kind, s: s, **extra):
    est = Estimator(settings_for(DRIVE, origin, **extra))
    for kind, s, _ in samples:
        assert (est.add_imu if kind == "imu" else est.add_gnss)(change(kind, copy.deepcopy(s)))
    return est


# -- sigmas ---------------------------------------------------------------------------------------
def test_sigmas_may_come_along_enu_or_as_horizontal_and_vertical():
    base = {"t": 1_717_236_000_000_000_000, "valid": True, "ecef_m": [4.9e6, -0.8e6, 3.97e6]}
    assert read_fix(dict(base, enu_sigma_m=[1.0, 2.0, 3.0])).enu_sigma_m == (1.0, 2.0, 3.0)
    assert read_fix(dict(base, sigma_h_m=1.5, sigma_v_m=2.5)).enu_sigma_m == (1.5, 1.5, 2.5)
    assert read_fix(dict(base, ecef_sigma_m=[1.0, 1.0, 1.0])).enu_sigma_m is None
    # ENU wins over ECEF (which lost the cross terms when it was made from ENU ones)
    both = read_fix(dict(base, ecef_sigma_m=[9.0, 9.0, 9.0], enu_sigma_m=[1.0, 1.0, 2.0]))
    assert both.enu_sigma_m == (1.0, 1.0, 2.0)


def test_a_fix_without_any_sigma_or_with_half_of_hv_is_malformed_and_says_why(drive):
    samples, origin = drive
    est = feed(samples[:50], origin)
    fix = copy.deepcopy(next(s for k, s, _ in samples[50:] if k == "gnss"))
    del fix["ecef_sigma_m"]
    assert est.add_gnss(dict(fix, sigma_h_m=1.0)) is False
    assert est.add_gnss(fix) is False
    assert est.input_rejected == {"malformed": 2}
    assert est.add_gnss(dict(fix, sigma_h_m=1.0, sigma_v_m=2.0)) is True


@pytest.mark.slow
@pytest.mark.parametrize("form", ["enu", "hv"])
def test_enu_and_hv_sigmas_say_what_ecef_ones_cannot(form):
    """The twins' receiver is 1.53 m along East and North, 2.45 m Up. Sent as ECEF sigmas
    (the diagonal of the rotated covariance, as BESTXYZ does) and turned back, the vertical
    leaks into North; sent along ENU, or as horizontal and vertical, it does not. The
    estimate is the same; its sigma is the honest one."""
    # the Gauss-Markov twin: its receiver reports the same sigmas at every epoch (the
    # standalone one's follow the satellites, which is not what this test is about)
    ecef = generate(Drive(duration_s=40.0, seed=5, gnss_errors="gauss_markov"))
    other = generate(Drive(duration_s=40.0, seed=5, sigma_form=form, gnss_errors="gauss_markov"))
    fix = next(s for k, s, _ in other[0] if k == "gnss")
    assert "ecef_sigma_m" not in fix
    a, b = feed(*ecef), feed(*other)
    sa, sb = a.state(), b.state()
    assert sa["gnss_used"] == sb["gnss_used"] > 300
    assert np.linalg.norm(np.subtract(sa["enu_m"], sb["enu_m"])) < 0.1
    east, north, up = sb["enu_sigma_m"]
    assert east == pytest.approx(north, rel=0.02) and 1.3 < east < 1.6 and 2.1 < up < 2.6
    assert sa["enu_sigma_m"][1] > 1.2 * north           # through ECEF, North took some of Up


# -- numpy --------------------------------------------------------------------------------------
def test_numpy_numbers_and_arrays_are_read_as_what_they_hold(drive):
    samples, origin = drive

    def as_numpy(kind, s):
        for name in ("accel_mps2", "gyro_radps", "ecef_m", "vel_ecef_mps"):
            if s.get(name) is not None:
                s[name] = np.array(s[name])
        s["t"] = np.int64(s["t"])
        if kind == "gnss":
            s["ecef_sigma_m"] = [np.float32(v) for v in s["ecef_sigma_m"]]
        return s
    plain, numpy = feed(samples, origin), feed(samples, origin, as_numpy)
    a, b = plain.state(), numpy.state()
    assert b["input_rejected"] == {} and b["gnss_used"] == a["gnss_used"]
    assert np.linalg.norm(np.subtract(a["enu_m"], b["enu_m"])) < 1e-3


# -- receivers without velocity ---------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("rate_hz", [10.0, 1.0])
def test_a_position_only_receiver_gives_a_heading_once_the_car_moves(rate_hz):
    drive = Drive(duration_s=80.0, seed=4, gnss_velocity=False, with_mag=False, gnss_rate_hz=rate_hz)
    samples, origin = generate(drive)
    est = Estimator(settings_for(drive, origin))
    yaw_err, valid_at = [], None
    for kind, s, truth in samples:
        if kind == "gnss":
            assert s["vel_ecef_mps"] is None
            est.add_gnss(s)
            continue
        est.add_imu(s)
        state = est.state()
        if state["heading_valid"] and valid_at is None:
            valid_at = truth.t_s
        if truth.t_s > 30.0:
            yaw_err.append(wrap_angle(state["yaw_rad"] - yaw_pitch_roll(truth.quat)[0]))
    assert valid_at is not None and valid_at < 16.0            # pulling away at 10 s
    assert state["heading_source"] == "course"
    assert math.degrees(math.sqrt(np.mean(np.square(yaw_err)))) < 3.0


# -- a receiver's velocity latency ---------------------------------------------------------------------
def test_a_receivers_velocity_latency_is_a_setting_for_receivers_that_do_not_send_it(drive):
    """The twins' velocities are 0.15 s old and say so; a receiver that does not (NMEA) is
    told by the setting: the same estimate."""
    samples, origin = drive
    latency = next(s["vel_latency_s"] for k, s, _ in samples if k == "gnss" and s["valid"])
    assert latency == pytest.approx(0.15)
    told = feed(samples, origin)
    silent = feed(samples, origin, lambda kind, s: dict(s, vel_latency_s=0.0) if kind == "gnss" else s,
                  gnss_vel_latency_s={"gnss0": 0.15})
    assert told.state()["enu_m"] == silent.state()["enu_m"]
    with pytest.raises(ValueError, match="gnss_vel_latency_s"):
        Estimator(settings_for(DRIVE, origin, gnss_vel_latency_s={"gnss0": 3.0}))


# -- standstill ---------------------------------------------------------------------------------------
def vibrating(samples, gyro_sigma=0.02, accel_sigma=0.4, seed=0):
    """The drive's IMU on an idling engine: much more noise than the Razor on the quiet car."""
    rng = np.random.default_rng(seed)
    out = []
    for kind, s, truth in samples:
        if kind == "imu":
            s = dict(s, gyro_radps=[v + rng.normal(0, gyro_sigma) for v in s["gyro_radps"]],
                     accel_mps2=[v + rng.normal(0, accel_sigma) for v in s["accel_mps2"]])
        out.append((kind, s, truth))
    return out


def parked_states(samples, origin, **extra):
    est = Estimator(settings_for(DRIVE, origin, **extra))
    still = []
    for kind, s, truth in samples:
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
        if kind == "imu" and 5.0 < truth.t_s < 9.5:              # parked until 10 s
            still.append(est.state()["standstill"])
    return est, still


def test_standstill_thresholds_are_learnt_from_the_first_seconds_parked(drive):
    samples, origin = drive
    quiet, still = parked_states(samples, origin)
    assert all(still[-200:])
    gyro, accel = quiet.standstill.thresholds
    assert gyro == GYRO_FLOOR_RADPS and ACCEL_FLOOR_MPS2 <= accel < 0.5    # the Razor's noise, 3 x
    # an idling engine: the Razor's thresholds would never call the car still; learnt ones do
    noisy = vibrating(samples)
    est, still = parked_states(noisy, origin, still_gyro_radps=0.01, still_accel_mps2=0.2)
    assert not any(still)
    est, still = parked_states(noisy, origin)
    assert all(still[-200:])
    gyro, accel = est.standstill.thresholds
    assert gyro > 0.03 and accel > 0.9
    assert not est.state()["standstill"]                          # and once moving, it is not
