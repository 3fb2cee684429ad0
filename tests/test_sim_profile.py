"""End to end through the `sim` compose profile, as `viena up` runs it: the real services
read the twins of the simulated car over their real wire protocols, and what they publish
agrees with the car's ground truth."""
from __future__ import annotations

import bisect
from contextlib import contextmanager
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pymap3d
import pytest
import zenoh

from vienatest import collect
from viena.common.config import load_zenoh_config
from viena.common.health import HEALTH
from viena.common.rotation import quat_to_matrix
from viena.services.estimator.state import STATE
from viena.services.gnss.model.fix import FIX
from viena.services.imu.model.sample import SAMPLE as IMU_SAMPLE
from viena.services.sim.model.truth import TRUTH
from viena.services.steering.client import SteeringClient
from viena.services.steering.model.state import STATE as STEERING

VIENA = [sys.executable, "-m", "viena.cli"]
LEVER_ARMS = {"gnss0": (-0.5, 1.0, 1.5), "gnss1": (0.5, 1.0, 1.5)}


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """The whole simulated car under supervisord, and a client session to its router."""
    import os
    env = dict(os.environ, VIENA_RUN=str(tmp_path_factory.mktemp("run")))
    env.pop("VIENA_ROUTER_PORT", None)
    up = subprocess.run([*VIENA, "up", "-d", "--free-ports"], env=env, capture_output=True,
                        text=True, timeout=120)
    try:
        assert up.returncode == 0, up.stderr
        saved = json.loads((Path(env["VIENA_RUN"]) / "env.json").read_text())
        router = f"tcp/127.0.0.1:{saved['VIENA_ROUTER_PORT']}"
        with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
            yield session
    finally:
        subprocess.run([*VIENA, "down", "--profile", "sim"], env=env, capture_output=True, timeout=60)


@contextmanager
def truth_recorder(session):
    """Every truth sample while the block runs, decoded."""
    truths: list[dict] = []
    sub = session.declare_subscriber("viena/elettra/sim/truth",
                                     lambda s: truths.append(TRUTH.decode(s.payload.to_bytes())))
    try:
        yield truths
    finally:
        sub.undeclare()


def nearest(truths: list[dict], t_ns: int) -> dict | None:
    times = [t["t"] for t in truths]
    i = bisect.bisect_left(times, t_ns)
    return truths[i] if 0 < i < len(times) else None


def test_every_program_reports_health(car):
    seen = {h["service"] + "/" + str(h["unit"]) for h in
            collect(car, "viena/elettra/**/health", 30, timeout=20, decode=HEALTH.decode)}
    assert {"sim/None", "gnss/gnss0", "gnss/gnss1", "imu/razor0"} <= seen


def test_gnss_fixes_within_noise_of_truth(car):
    with truth_recorder(car) as truths:
        fixes = collect(car, "viena/elettra/gnss/*/fix", 60, timeout=30, decode=FIX.decode)
    assert len(fixes) == 60
    errors = []
    for fix in fixes:
        t = nearest(truths, fix["t"])
        if t is None or not fix["valid"]:
            continue
        antenna = np.array(t["enu_m"]) + quat_to_matrix(t["quat"]) @ np.array(LEVER_ARMS[fix["unit"]])
        antenna += np.array(t["vel_enu_mps"]) * (fix["t"] - t["t"]) / 1e9
        enu = np.array(pymap3d.ecef2enu(*fix["ecef_m"], *t["origin"]))
        error = float(np.linalg.norm(enu - antenna))
        assert error < 4 * np.linalg.norm(fix["ecef_sigma_m"]), fix
        errors.append(error)
    assert len(errors) > 40
    assert np.median(errors) < 3.0          # seed table 5.2: about 1.8 m CEP


def test_imu_samples_agree_with_truth(car):
    with truth_recorder(car) as truths:
        samples = collect(car, "viena/elettra/imu/razor0/sample", 160, timeout=30, decode=IMU_SAMPLE.decode)
    assert len(samples) == 160
    seqs = [s["seq"] for s in samples]
    assert seqs == sorted(seqs)
    diffs_f, diffs_w = [], []
    for s in samples:
        t = nearest(truths, s["t"])
        if t is None:
            continue
        diffs_f.append(np.array(s["accel_mps2"]) - np.array(t["specific_force_mps2"]))
        diffs_w.append(np.array(s["gyro_radps"]) - np.array(t["gyro_radps"]))
    assert len(diffs_f) > 100
    # calibrated, in the body frame, SI: the mean error is the sensors' residual bias
    assert np.all(np.abs(np.mean(diffs_f, axis=0)) < 0.3)        # m/s^2
    assert np.all(np.abs(np.mean(diffs_w, axis=0)) < 0.02)       # rad/s


def test_estimator_state_tracks_truth(car):
    with truth_recorder(car) as truths:
        # past alignment: the car is parked 10 s, then drives
        end = time.monotonic() + 90.0
        states = []
        while time.monotonic() < end:
            states = collect(car, "viena/elettra/estimator/state", 20, timeout=10, decode=STATE.decode)
            if states and states[-1]["position_valid"] and states[-1]["aligned"]:
                break
        states = collect(car, "viena/elettra/estimator/state", 80, timeout=20, decode=STATE.decode)
    assert len(states) == 80
    errors = []
    for s in states:
        t = nearest(truths, s["t"])
        if t is None:
            continue
        assert all(np.isfinite(s["enu_m"])) and all(np.isfinite(s["quat"]))
        errors.append(np.linalg.norm(np.array(s["enu_m"][:2]) - np.array(t["enu_m"][:2])))
    assert len(errors) > 50
    assert np.median(errors) < 3.0


def test_steering_comes_up_calibrated_and_a_setpoint_turns_the_car(car):
    end = time.monotonic() + 60
    state = None
    while time.monotonic() < end:                 # the twin sweeps lock to lock first
        states = collect(car, "viena/elettra/steering/state", 1, timeout=5, decode=STEERING.decode)
        state = states[-1] if states else None
        if state and state["phase"] == "ready":
            break
        time.sleep(0.5)
    assert state and state["phase"] == "ready" and not state["armed"], state
    calibration = state["calibration"]
    assert calibration["state"] == "done" and 90_000 <= calibration["span_qc"] <= 100_000, calibration

    client = SteeringClient(car)
    reply = client.arm()
    assert reply["status"] == "accepted", reply
    try:
        with truth_recorder(car) as truths:
            last = client.hold(10.0, seconds=3.0)
        assert last["status"] in ("accepted", "clamped"), last
        wheel_deg = np.degrees(truths[-1]["wheel_angle_rad"])
        assert abs(wheel_deg - 10.0) < 1.0, wheel_deg           # the simulated car turned
        assert truths[-1]["gyro_radps"][2] > 0                   # to the left
    finally:
        assert client.disarm()["status"] == "accepted"
