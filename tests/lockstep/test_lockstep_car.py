"""The sim profile in lockstep: every program of `viena up` in one process, on a virtual
clock, over the in-memory bus. What it publishes agrees with the car's truth as the real
profile's does (tests/test_sim_profile.py), the same seed gives the same bytes, and a
killed program comes back as supervisord would bring it back."""
from __future__ import annotations

import bisect
import hashlib

import numpy as np
import pymap3d
import pytest

from viena.common import clock
from viena.common.rotation import quat_to_matrix
from viena.common.samples.estimator import STATE
from viena.common.samples.fix import FIX
from viena.common.samples.health import HEALTH
from viena.common.samples.imu import SAMPLE as IMU_SAMPLE
from viena.common.samples.steering import STATE as STEERING
from viena.common.samples.truth import TRUTH
from viena.lockstep_car import LockstepCar, profile_programs
from viena.services.steering.client import SteeringClient

LEVER_ARMS = {"gnss0": (-0.5, 1.0, 1.5), "gnss1": (0.5, 1.0, 1.5)}


@pytest.fixture(scope="module")
def drive():
    """The whole sim profile, 40 s of it: (car, truths, fixes, imu samples, states, healths)."""
    with LockstepCar(seed=1) as car:
        watched = {name: car.collect(key, decode) for name, key, decode in (
            ("truth", car.key("sim", "truth"), TRUTH.decode),
            ("fix", car.key("gnss", "*", "fix"), FIX.decode),
            ("imu", car.key("imu", "razor0", "sample"), IMU_SAMPLE.decode),
            ("state", car.key("estimator", "state"), STATE.decode),
            ("steering", car.key("steering", "state"), STEERING.decode),
            ("health", car.key("**", "health"), HEALTH.decode))}
        car.run_for(40)
        yield car, watched


def nearest(truths: list[dict], t_ns: int) -> dict | None:
    times = [t["t"] for t in truths]
    i = bisect.bisect_left(times, t_ns)
    return truths[i] if 0 < i < len(times) else None


def test_the_profile_is_the_one_viena_up_runs():
    names = [p.name for p in profile_programs()]
    assert names == ["sim", "gnss0", "gnss1", "razor0", "steering", "estimator", "pilot"]


def test_every_program_reports_health_and_every_key_flows_at_its_rate(drive):
    car, got = drive
    assert {f"{h['service']}/{h['unit']}" for h in got["health"]} == {
        "sim/None", "gnss/gnss0", "gnss/gnss1", "imu/razor0", "steering/None", "estimator/None", "pilot/None"}
    assert len(got["truth"]) == pytest.approx(100 * 40, abs=2)
    assert len(got["fix"]) == pytest.approx(2 * 20 * 40, rel=0.03)
    assert len(got["imu"]) > 80 * 35                       # after the board's 1 s boot
    assert len(got["steering"]) == pytest.approx(50 * 40, rel=0.1)
    assert car.clock.errors == []


def test_gnss_fixes_within_noise_of_truth(drive):
    _, got = drive
    errors = []
    for fix in got["fix"][400:]:
        t = nearest(got["truth"], fix["t"])
        if t is None or not fix["valid"]:
            continue
        antenna = np.array(t["enu_m"]) + quat_to_matrix(t["quat"]) @ np.array(LEVER_ARMS[fix["unit"]])
        antenna += np.array(t["vel_enu_mps"]) * (fix["t"] - t["t"]) / 1e9
        enu = np.array(pymap3d.ecef2enu(*fix["ecef_m"], *t["origin"]))
        error = float(np.linalg.norm(enu - antenna))
        assert error < 4 * np.linalg.norm(fix["ecef_sigma_m"]), fix
        errors.append(error)
    assert len(errors) > 1000
    assert np.median(errors) < 3.0          # about 1.8 m CEP


def test_imu_samples_agree_with_truth(drive):
    _, got = drive
    seqs = [s["seq"] for s in got["imu"]]
    assert seqs == sorted(seqs)
    diffs_f, diffs_w = [], []
    for s in got["imu"]:
        t = nearest(got["truth"], s["t"])
        if t is not None:
            diffs_f.append(np.array(s["accel_mps2"]) - np.array(t["specific_force_mps2"]))
            diffs_w.append(np.array(s["gyro_radps"]) - np.array(t["gyro_radps"]))
    assert np.all(np.abs(np.mean(diffs_f, axis=0)) < 0.3)        # m/s^2
    assert np.all(np.abs(np.mean(diffs_w, axis=0)) < 0.02)       # rad/s


def test_the_estimate_tracks_the_truth_once_aligned(drive):
    _, got = drive
    ready = [s for s in got["state"] if s["position_valid"] and s["aligned"]]
    assert len(ready) > 1000
    errors = [np.linalg.norm(np.array(s["enu_m"][:2]) - np.array(t["enu_m"][:2]))
              for s in ready[-800:] if (t := nearest(got["truth"], s["t"])) is not None]
    assert np.median(errors) < 3.0


def test_the_steering_comes_up_calibrated_and_a_setpoint_turns_the_car(drive):
    car, got = drive
    state = got["steering"][-1]
    assert state["phase"] == "ready" and not state["armed"], state
    assert state["calibration"]["state"] == "done" and 90_000 <= state["calibration"]["span_qc"] <= 100_000
    client = SteeringClient(car.session("person"))
    reply = client.arm()
    assert reply["status"] == "accepted", reply
    try:
        last = client.hold(10.0, seconds=3.0)
        assert last["status"] in ("accepted", "clamped"), last
        truth = got["truth"][-1]
        assert abs(np.degrees(truth["wheel_angle_rad"]) - 10.0) < 1.0
        assert truth["gyro_radps"][2] > 0                   # to the left
    finally:
        assert client.disarm()["status"] == "accepted"


def test_a_calibration_restart_is_swept_again_by_the_simulated_person():
    """Issue 15: a restart left the steering calibrating for good; the person at the wheel
    now sweeps it again, as asked, and the steering comes back ready."""
    with LockstepCar(seed=3, programs=["sim", "steering"]) as car:
        client = SteeringClient(car.session("person"), timeout_s=5.0)

        def calibration() -> str | None:        # None until the steering answers
            return client.ask("calibration", {}).get("calibration", {}).get("state")

        assert car.run_until(lambda: calibration() == "done", within_s=60, step_s=0.5)
        assert client.ask("calibration", {"restart": True})["status"] == "accepted"
        assert calibration() == "sweeping"
        assert car.run_until(lambda: calibration() == "done", within_s=90, step_s=0.5)
        assert 90_000 <= client.ask("calibration", {})["calibration"]["span_qc"] <= 100_000


def _bytes_of_a_drive(seed: int, seconds: float) -> tuple[str, int]:
    with LockstepCar(seed=seed) as car:
        everything = car.collect(car.key("**"))
        car.run_for(seconds)
    digest = hashlib.sha256()
    for key, payload in everything:
        digest.update(key.encode() + b"\0" + payload)
    return digest.hexdigest(), len(everything)


def test_the_same_seed_gives_the_same_bytes_on_every_key():
    first, n = _bytes_of_a_drive(5, 12)
    again, m = _bytes_of_a_drive(5, 12)
    other, _ = _bytes_of_a_drive(6, 12)
    assert n > 4000 and (again, m) == (first, n)
    assert other != first


def test_a_killed_receiver_goes_silent_and_comes_back_on_restart():
    with LockstepCar(seed=2, programs=["sim", "gnss0"]) as car:
        fixes = car.collect(car.key("gnss", "gnss0", "fix"), FIX.decode)
        car.run_for(3)
        assert len(fixes) >= 50
        car.kill("gnss0")
        before = len(fixes)
        car.run_for(3)
        assert len(fixes) == before                    # SIGKILL: not one more fix
        alive = car.session("probe").liveliness().get(car.key("alive", "gnss", "gnss0"), timeout=1)
        assert not [r for r in alive if r.ok is not None]
        car.start("gnss0")
        assert car.run_until(lambda: len(fixes) > before + 20, within_s=10)
        assert fixes[-1]["valid"]


def test_a_sim_that_falls_behind_catches_the_car_up_to_the_wall_clock():
    """A sim starved for over half a second steps the car through the time it missed: its
    truth (and the GNSS twins' times) stay on the clock the IMU's samples are stamped with.
    Skipping the time instead left them a second behind the IMU for good."""
    with LockstepCar(seed=3, programs=["sim"]) as car:
        truths = car.collect(car.key("sim", "truth"), TRUTH.decode)
        car.run_for(2)
        sim = car.services["sim"]
        step, stalled = sim.car.step, []

        def stall_once(dt):
            if not stalled:
                stalled.append(True)
                clock.sleep(1.5)                    # the sim's thread held up 1.5 s
            return step(dt)
        sim.car.step = stall_once
        car.run_for(3)
        assert stalled
        behind_s = (car.clock.time_ns() - truths[-1]["t"]) / 1e9
        assert 0 <= behind_s < 0.05, behind_s
