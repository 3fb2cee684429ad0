"""The estimator on the car's real recordings (shipped in data/).

- the parked Razor recordings (2017, traction motor off and at 0, 10, 20 Hz): the static
  alignment gives roll and pitch that stay put and agree with the mean specific force;
- the 2016 NovAtel drive (BESTXYZ, 10 Hz, 130 rows without a solution, one 11.8 m jump in
  the receiver's own track): GNSS only, it runs through without a NaN and without a jump
  the receiver did not make.
"""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from estimator_recordings import IMU_PARKED, gnss_drive_fixes, razor_parked_samples

from viena.common.samples.estimator import STATE
from viena.services.estimator.estimator import Estimator


@pytest.mark.parametrize("path", IMU_PARKED, ids=lambda p: p.stem)
def test_static_alignment_on_the_parked_car_gives_stable_roll_and_pitch(path):
    samples = razor_parked_samples(path)
    est = Estimator()
    tilt = []
    for s in samples:
        assert est.add_imu(s)
        state = est.state()
        if state["aligned"]:
            tilt.append((state["roll_rad"], state["pitch_rad"]))     # about forward, about right
    assert state["mode"] == "attitude" and not state["position_valid"]
    tilt = np.degrees(np.array(tilt))
    assert len(tilt) > 0.9 * len(samples)
    # stable: the motor's vibration (10, 20 Hz) shakes the accelerometer, not the attitude
    assert tilt.std(axis=0).max() < 0.1
    assert np.ptp(tilt, axis=0).max() < 0.5
    # and right: the direction of the mean specific force (the quantised readings make
    # Madgwick's fixed point a median rather than a mean: a fifth of a degree apart)
    f = np.mean([s["accel_mps2"] for s in samples], axis=0)
    roll = math.degrees(math.atan2(-f[0], f[2]))                  # state/2: R = Rz Rx(pitch) Ry(roll)
    pitch = math.degrees(math.atan2(f[1], math.hypot(f[0], f[2])))
    assert tilt.mean(axis=0) == pytest.approx((roll, pitch), abs=0.3)
    # the car leans about 1.5 deg to its right and 3.4 deg nose down (as the board is mounted)
    assert tilt.mean(axis=0) == pytest.approx((1.5, -3.4), abs=0.3)


@pytest.fixture(scope="module")
def drive_replay():
    fixes = gnss_drive_fixes()
    est = Estimator()
    states = []
    for fix in fixes:
        est.add_gnss(fix)
        state = est.state()
        STATE.encode(dict(state))                  # publishable: no NaN, schema holds
        states.append(state)
    return fixes, est, states


def test_the_2016_drive_runs_through_gnss_only(drive_replay):
    fixes, est, states = drive_replay
    last = states[-1]
    assert last["mode"] == "gnss_only" and last["position_valid"]
    assert last["origin_source"] == "first_fix"
    # every fix was looked at; the 130 without a solution were refused for their status,
    # those from fewer than 5 satellites by the admission (and the 10 s of probation after
    # each spell of them), no usable fix by the filter's own gate
    assert last["counts"]["gnss"] == len(fixes)
    assert last["gnss_rejected"]["status"] == sum(not f["valid"] for f in fixes) == 130
    rejected = last["gnss_rejected"]
    few = sum(f["valid"] and f["sats_used"] < 5 for f in fixes)
    assert 0.9 * few <= rejected["quality_sats"] <= few          # (some were decimated first)
    assert set(rejected) <= {"status", "sigma", "probation", "quality_sats", "quality_sigma_h"}
    assert last["gnss_used"] > 0.85 * len(fixes)
    assert last["input_rejected"] == {}
    assert last["counts"]["resets"] == 0
    for s in states:
        assert all(math.isfinite(v) for v in s["enu_m"] + s["vel_enu_mps"] + s["quat"])


def test_the_2016_drive_has_no_jump_the_receiver_did_not_make(drive_replay):
    fixes, est, states = drive_replay
    origin = est.frame.origin
    used = [(f, s) for f, s in zip(fixes, states) if f["valid"] and s["position_valid"]]
    gnss = np.array([pymap3d.ecef2enu(*f["ecef_m"], *origin) for f, _ in used])[:, :2]
    mine = np.array([s["enu_m"][:2] for s in states if s["position_valid"]])
    gnss_steps = np.linalg.norm(np.diff(gnss, axis=0), axis=1)
    my_steps = np.linalg.norm(np.diff(mine, axis=0), axis=1)
    # the receiver once jumps 11.8 m in 0.1 s; the car never did, and neither does the estimate
    assert gnss_steps.max() > 10.0
    assert my_steps.max() < 1.5
    # through the gaps it coasts at the speed the car had (<= 5 m/s) instead of jumping
    t = np.array([s["t"] for s in states if s["position_valid"]]) * 1e-9
    speeds = my_steps / np.maximum(np.diff(t), 1e-3)
    assert np.percentile(speeds, 99.9) < 6.0
    # and it stays on the receiver's track: within its sigmas, never off to (100, 0, 0)
    err = np.linalg.norm(np.array([s["enu_m"][:2] for _, s in used]) - gnss, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 1.5 and err.max() < 12.0
