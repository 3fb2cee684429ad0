"""End to end through the `sim` compose profile, as `viena up` runs it: real processes under
supervisord, real zenoh, the twins on real TCP ports. This is the real-time tier's car: it
comes up, every program reports, a setpoint makes the round trip to the drive and turns
the car, and the real `zenoh` CLI and `viena sub` watch it. What the car's data says
against its truth is checked in virtual time (tests/lockstep/test_lockstep_car.py), where
it is deterministic and takes a fraction of the time."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

import msgpack
import numpy as np
import pytest
from vienatest import collect, collect_until, open_session, sim_profile_up, viena, wait_for_subscriber, wait_until

from viena.common.samples.health import HEALTH
from viena.common.samples.steering import STATE as STEERING
from viena.common.samples.truth import TRUTH
from viena.services.steering.client import SteeringClient

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=5)]  # the whole sim profile

ZENOH_CLI = shutil.which("zenoh", path=str(Path(sys.executable).parent)) or shutil.which("zenoh")
LEVER_ARMS = {"gnss0": (-0.5, 1.0, 1.5), "gnss1": (0.5, 1.0, 1.5)}


@pytest.fixture(scope="module")
def sim_profile(tmp_path_factory):
    """The whole simulated car under supervisord, once for the module: (environment, router)."""
    with sim_profile_up(tmp_path_factory.mktemp("run")) as up:
        yield up


@pytest.fixture(scope="module")
def car(sim_profile):
    """A client session to the car's router."""
    with open_session(sim_profile[1]) as session:
        yield session


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


def programs(healths: list[dict]) -> set[str]:
    return {h["service"] + "/" + str(h["unit"]) for h in healths}


def test_every_program_reports_health(car):
    expected = {"sim/None", "gnss/gnss0", "gnss/gnss1", "imu/razor0"}
    seen = programs(collect_until(car, "viena/elettra/**/health", lambda got: expected <= programs(got),
                                  timeout=20, decode=HEALTH.decode))
    assert expected <= seen


def test_the_corrections_chain_stays_off_without_rtk(sim_profile):
    """`viena up` without --rtk: the caster's twin and viena-ntrip are left off, and `up -d`
    did not wait for them (tests/test_rtk_car.py runs them)."""
    from vienatest import supervisor
    states = {i["name"]: i["statename"] for i in supervisor(Path(sim_profile[0]["VIENA_RUN"])).getAllProcessInfo()}
    assert states["caster"] == states["ntrip"] == "STOPPED"
    assert states["gnss0"] == states["estimator"] == "RUNNING"


def test_steering_comes_up_calibrated_and_a_setpoint_turns_the_car(car):
    latest = {}
    sub = car.declare_subscriber("viena/elettra/steering/state",
                                 lambda s: latest.update(state=STEERING.decode(s.payload.to_bytes())))
    try:                                          # the twin sweeps lock to lock first
        wait_until(lambda: latest and latest["state"]["phase"] == "ready", 60, period=0.05)
    finally:
        sub.undeclare()
    state = latest.get("state")
    assert state and state["phase"] == "ready" and not state["armed"], state
    calibration = state["calibration"]
    assert calibration["state"] == "done" and 90_000 <= calibration["span_qc"] <= 100_000, calibration

    # a turned wheel turns only a moving car: past the parked start (the tests before this
    # one may have taken less than that)
    collect_until(car, "viena/elettra/sim/truth", lambda got: got and got[-1]["speed_mps"] > 1,
                  timeout=60, decode=TRUTH.decode)
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


def test_sim_profile_truth_through_zenoh_cli_and_viena_sub(sim_profile):
    env, router = sim_profile
    assert ZENOH_CLI, "the zenoh CLI (zenoh-cli package) must be installed"
    cli = subprocess.Popen(
        [ZENOH_CLI, "--mode", "client", "--connect", router, "--cfg", "scouting/multicast/enabled:false",
         "subscribe", "-k", "viena/elettra/sim/truth", "--decoder", "msgpack"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = cli.stdout.readline()
        second = cli.stdout.readline()
    finally:
        cli.terminate()
        cli.wait(timeout=10)
    for line in (first, second):
        sample = json.loads(line)
        assert sample["lat_deg"] == pytest.approx(38.7369, abs=0.01)
        assert len(sample["ecef_m"]) == 3 and len(sample["quat"]) == 4
    assert json.loads(second)["seq"] > json.loads(first)["seq"]

    sub = viena("sub", "--connect", router, "viena/elettra/sim/truth", "-n", "3", "--timeout", "20", env=env)
    assert sub.returncode == 0, sub.stderr
    lines = sub.stdout.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("viena/elettra/sim/truth {") for line in lines)

    as_json = viena("sub", "--connect", router, "viena/elettra/sim/truth", "-n", "1", "--json",
                    "--timeout", "20", env=env)
    record = json.loads(as_json.stdout)
    assert record["key"] == "viena/elettra/sim/truth"
    assert record["encoding"] == "application/msgpack;viena.sim.truth/1"
    assert record["value"]["speed_mps"] >= 0


def test_zenoh_cli_put_with_msgpack_encoder(sim_profile):
    env, router = sim_profile
    with open_session(router) as s, open_session(router) as probe:
        got = []
        t = threading.Thread(target=lambda: got.extend(collect(s, "viena/elettra/test/put", 1, timeout=20)))
        t.start()
        assert wait_for_subscriber(probe, "viena/elettra/test/put")
        subprocess.run([ZENOH_CLI, "--mode", "client", "--connect", router, "--cfg",
                        "scouting/multicast/enabled:false", "put", "-k", "viena/elettra/test/put",
                        "--encoder", "msgpack", "-v", '{"a": 1}'], check=True, timeout=30)
        t.join()
    assert got and msgpack.unpackb(got[0][1]) == {"a": 1}
