"""An estimator (re)started while the car drives: it must not learn that a moving car's IMU
is what standing looks like, nor believe the IMU alone over the receivers' Doppler speeds.

Before the fix, the standstill thresholds were learnt from the first `align_s` of samples
whatever the car did; started at 30 s into this drive, the car then looked "still" on the
straights, the admission's drift check failed both receivers' true 4 m/s for 148 fixes,
and the position came after 19 s instead of the 10 s hold (services/estimator/standstill.py,
doppler.py)."""
from __future__ import annotations

import math

import pytest
from estimator_helpers import generate

from benchmarks.simdrive import Drive
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.standstill import ACCEL_FLOOR_MPS2, GYRO_FLOOR_RADPS

ARMS = {"gnss0": [-0.5, 1.0, 1.5], "gnss1": [0.5, 1.0, 1.5]}
DRIVE = Drive(duration_s=75.0, seed=3, lever_arm_m=tuple(ARMS["gnss0"]), second_antenna_m=tuple(ARMS["gnss1"]))
#: into the drive (parked for its first 10 s), s: a parked start, and starts while driving
STARTS = (0.0, 30.0, 50.0)
RUN_S = 25.0


@pytest.fixture(scope="module")
def drive():
    samples, origin = generate(DRIVE)
    return samples, origin


def start_at(samples, origin, start_s: float) -> dict:
    """Start an estimator (the admission's default 10 s hold) `start_s` into the drive and
    feed it RUN_S; what it did."""
    est = Estimator({"origin": list(origin), "gnss_lever_arm_m": ARMS})
    t0 = samples[0][1]["t"]
    first = t0 + int(start_s * 1e9)
    out = {"position_after_s": None, "still_moving_s": 0.0, "aligned_stood_moving": False}
    speeds = {}                       # each receiver's latest Doppler speed: what GNSS says
    for kind, s, _ in samples:
        if s["t"] < first:
            continue
        if s["t"] > first + int(RUN_S * 1e9):
            break
        if kind == "gnss":
            est.add_gnss(s)
            speeds[s["unit"]] = math.dist(s["vel_ecef_mps"], (0.0, 0.0, 0.0))
            continue
        was_aligned = est.attitude.aligned
        est.add_imu(s)
        moving = len(speeds) == 2 and min(speeds.values()) > 1.0
        if est.standstill.still and moving:
            out["still_moving_s"] += 1.0 / DRIVE.imu_rate_hz
        if not was_aligned and est.attitude.aligned and moving and not est.kf.initialized:
            out["aligned_stood_moving"] = True          # aligned as if parked, GNSS saying 1 m/s+
        if out["position_after_s"] is None and est.kf.initialized:
            out["position_after_s"] = (s["t"] - first) * 1e-9
    out["state"], out["estimator"] = est.state(), est
    return out


@pytest.mark.parametrize("start_s", STARTS)
def test_a_start_while_driving_gets_a_position_as_fast_as_a_parked_one(drive, start_s):
    samples, origin = drive
    run = start_at(samples, origin, start_s)
    state = run["state"]
    # no "standing" while the receivers say the car drives (it moves at 3-5 m/s from 10 s)
    assert run["still_moving_s"] == 0.0
    assert not run["aligned_stood_moving"]
    # the receivers move truthfully: none of their fixes is refused for drifting
    assert state["gnss_rejected"].get("quality_drift", 0) == 0
    # both in use after the admission's 10 s hold, the position with the first of them
    assert 10.0 <= run["position_after_s"] < 10.5
    assert state["gnss_admission"] == {"gnss0": "in use", "gnss1": "in use"}
    assert state["position_valid"] and state["heading_valid"] and state["counts"]["resets"] == 0


def test_thresholds_are_learnt_only_while_gnss_says_the_car_stands(drive):
    samples, origin = drive
    parked = start_at(samples, origin, 0.0)["estimator"].standstill
    # parked for the drive's first 10 s: learnt then (the Razor's noise, 3 x), GNSS agreeing
    gyro, accel = parked.thresholds
    assert gyro == GYRO_FLOOR_RADPS and ACCEL_FLOOR_MPS2 <= accel < 0.5 and parked.confirmed
    est = Estimator({"origin": list(origin), "gnss_lever_arm_m": ARMS})
    t0 = samples[0][1]["t"]
    for kind, s, _ in samples:
        if s["t"] >= t0 + 30_000_000_000:
            (est.add_imu if kind == "imu" else est.add_gnss)(s)
    # started while driving, never stopped since: nothing learnt, the Razor's floors judge
    assert est.standstill.thresholds == (None, None)
