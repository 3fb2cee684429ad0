"""The simulated car as the real one runs: `viena up --secure`, every program on TLS with
its own certificate, the router enforcing the roles. Then what a pilot, an observer and
an impostor can do to it, through the real services."""
from __future__ import annotations

import json
import os
import queue
import shlex
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh
from vienatest import Hijacker, collect, collect_until, wait_for_port, wait_for_subscriber, wait_until

from viena.common.config import load_zenoh_config
from viena.common.samples.estimator import STATE
from viena.common.samples.fix import FIX
from viena.common.samples.health import HEALTH
from viena.common.samples.steering import STATE as STEERING
from viena.common.secure import secure_client
from viena.services.steering.client import SteeringClient

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=5)]  # the whole secured profile

VIENA = [sys.executable, "-m", "viena.cli"]
CAR = "viena/elettra"
README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.fixture(scope="module")
def car(tmp_path_factory, store):
    """The sim profile with TLS and access control; yields (environment, router port)."""
    env = dict(os.environ, VIENA_RUN=str(tmp_path_factory.mktemp("run")), VIENA_KEYS=str(store.dir))
    for name in ("VIENA_ROUTER_PORT", "VIENA_LINK", "VIENA_IDENTITY"):
        env.pop(name, None)
    up = subprocess.run([*VIENA, "up", "--secure", "-d", "--free-ports"], env=env, capture_output=True,
                        text=True, timeout=120)
    try:
        assert up.returncode == 0, up.stderr
        assert "TLS and access control" in up.stderr
        saved = json.loads((Path(env["VIENA_RUN"]) / "env.json").read_text())
        wait_for_port(int(saved["VIENA_ROUTER_PORT"]))   # supervisord says RUNNING before it listens
        yield env, int(saved["VIENA_ROUTER_PORT"])
    finally:
        subprocess.run([*VIENA, "down", "--profile", "sim"], env=env, capture_output=True, timeout=60)


@contextmanager
def session_as(store, car, name: str):
    _, port = car
    conf = load_zenoh_config(mode="client", connect=[f"tls/localhost:{port}"])
    secure_client(conf, store, name)
    with zenoh.open(conf) as session:
        yield session


def estimator_state(session) -> dict:
    return collect(session, f"{CAR}/estimator/state", 1, timeout=30, decode=STATE.decode)[0]


def test_every_program_runs_with_its_own_certificate(store, car):
    expected = {"sim/None", "gnss/gnss0", "gnss/gnss1", "imu/razor0", "steering/None", "estimator/None"}

    def programs(healths: list[dict]) -> set[str]:
        return {h["service"] + "/" + str(h["unit"]) for h in healths}
    with session_as(store, car, "observer") as observer:
        seen = programs(collect_until(observer, f"{CAR}/**/health", lambda got: expected <= programs(got),
                                      timeout=20, decode=HEALTH.decode))
        assert expected <= seen
        assert estimator_state(observer)["gnss_live"] == ["gnss0", "gnss1"]


def test_an_observer_cannot_arm_steer_or_calibrate(store, car):
    with session_as(store, car, "observer") as observer:
        client = SteeringClient(observer, timeout_s=1.0)
        armed = client.arm()
        client.lease = "a-lease-the-observer-made-up"            # to sign a setpoint with at all
        for reply in (armed, client.setpoint(5.0), client.ask("calibration", {})):
            assert reply["status"] == "rejected" and "no answer" in reply["reason"]
        state = collect(observer, f"{CAR}/steering/state", 1, timeout=5, decode=STEERING.decode)[0]
        assert state["armed"] is False


def spoof_fix(real: dict, unit: str) -> bytes:
    return FIX.encode({**real, "unit": unit, "t": time.time_ns(), "seq": 1})


def test_a_fix_spoofed_by_an_observer_never_reaches_the_estimator(store, car):
    if not (store.dir / "spoof0.pem").exists():
        store.issue("gnss", "spoof0")          # the control: a GNSS identity may publish it
    with session_as(store, car, "observer") as observer:
        real = collect(observer, f"{CAR}/gnss/gnss0/fix", 1, timeout=10, decode=FIX.decode)[0]
        for _ in range(20):
            observer.put(f"{CAR}/gnss/spoof0/fix", spoof_fix(real, "spoof0"))
            time.sleep(0.05)
        assert "spoof0" not in estimator_state(observer)["gnss_live"]
    # the same fix from an identity whose role allows it does reach the estimator (after the
    # router restarts: it reads the identities when it starts)
    _restart_router(car[0])
    with session_as(store, car, "spoof0") as gnss, session_as(store, car, "observer") as observer:
        # the estimator is back on the restarted router
        assert wait_for_subscriber(gnss, f"{CAR}/gnss/spoof0/fix", timeout=30)
        for _ in range(20):
            gnss.put(f"{CAR}/gnss/spoof0/fix", spoof_fix(real, "spoof0"))
            time.sleep(0.05)
        assert "spoof0" in estimator_state(observer)["gnss_live"]


def _restart_router(env: dict) -> None:
    run = env["VIENA_RUN"]
    done = subprocess.run([sys.executable, "-m", "supervisor.supervisorctl", "-s", f"unix://{run}/supervisor.sock",
                           "restart", "router"], env=env, capture_output=True, text=True, timeout=30)
    assert "started" in done.stdout, done.stdout + done.stderr


def wait_steering_ready(session) -> None:
    """The twin sweeps lock to lock after power-up; arming waits for the calibration."""
    end, state = time.monotonic() + 60, None
    while time.monotonic() < end:
        states = collect(session, f"{CAR}/steering/state", 1, timeout=5, decode=STEERING.decode)
        state = states[-1] if states else None
        if state and state["phase"] == "ready":
            return
    pytest.fail(f"the steering never became ready: {state}")


def test_a_pilot_steers_and_a_second_pilot_is_refused(store, car):
    if not (store.dir / "alice.pem").exists():
        store.issue("pilot", "alice")
        _restart_router(car[0])
    with session_as(store, car, "pilot") as pilot, session_as(store, car, "alice") as alice:
        wait_steering_ready(pilot)
        owner = SteeringClient(pilot)
        arm = owner.arm()
        assert arm["status"] == "accepted", arm
        try:
            second = SteeringClient(alice).arm()
            assert second["status"] == "rejected" and second["reason"] == "armed by another client"
            reply = owner.setpoint(arm["angle_deg"] + 2.0)
            assert reply["status"] in ("accepted", "clamped"), reply
            stolen = SteeringClient(alice)
            stolen.lease = "not-the-lease"
            assert stolen.setpoint(0.0)["status"] == "rejected"
            # alice may read everything, the owner's setpoint puts too: she steers with none of it
            mallory, stop = Hijacker(alice), threading.Event()

            def stream():
                while not stop.wait(0.05):
                    owner.put_setpoint(arm["angle_deg"] + 2.0)
            streamer = threading.Thread(target=stream, daemon=True)
            streamer.start()
            try:
                assert wait_until(lambda: len(mallory.setpoints) >= 5, 10.0), "a pilot sees the setpoints"
                for _ in range(3):
                    mallory.attack()
                assert mallory.sent > 0 and mallory.accepted == [], mallory.accepted[:2]
            finally:
                stop.set()
                streamer.join(5)
                mallory.close()
        finally:
            assert owner.disarm()["status"] == "accepted"


def readme_lines(prefix: str) -> list[str]:
    return [line.strip() for line in README.read_text().splitlines() if line.strip().startswith(prefix)]


def test_the_zenoh_cli_works_as_the_readme_shows(store, car, tmp_path):
    env = dict(car[0])
    commands = {}
    for line in readme_lines("viena keys zenoh-config") + readme_lines("zenoh --config"):
        commands.setdefault(line.split(" > ")[0] if " > " in line else line, line)
    assert len(commands) >= 5, "the README's Security section shows these commands"

    def sh(line: str) -> subprocess.CompletedProcess:
        # the README's lines as a shell runs them: `viena` and `zenoh` from this virtualenv
        return subprocess.run(line, shell=True, cwd=tmp_path, capture_output=True, text=True, timeout=30,
                              env={**env, "PATH": f"{Path(sys.executable).parent}:{env['PATH']}"})

    for line in readme_lines("viena keys zenoh-config"):
        assert sh(line).returncode == 0, line
    pilot_arm = next(iter(readme_lines("zenoh --config pilot.json5 get -s viena/elettra/steering/arm")))
    observer_arm = next(iter(readme_lines("zenoh --config observer.json5 get -s viena/elettra/steering/arm")))
    estop = next(iter(readme_lines("zenoh --config observer.json5 put -k viena/elettra/steering/estop")))

    with session_as(store, car, "observer") as observer:
        wait_steering_ready(observer)
    answer = sh(pilot_arm)
    reply = json.loads(answer.stdout.strip().splitlines()[-1])
    assert reply["status"] == "accepted" and reply["lease"], answer.stdout + answer.stderr
    assert sh(observer_arm).stdout.strip() == ""             # dropped by the router: no answer
    with session_as(store, car, "observer") as observer:
        states: queue.Queue = queue.Queue()
        observer.declare_subscriber(f"{CAR}/steering/state",
                                    lambda s: states.put(STEERING.decode(s.payload.to_bytes())))
        assert sh(estop).returncode == 0
        end = time.monotonic() + 5
        while time.monotonic() < end:
            if not states.get(timeout=1)["armed"]:
                break
        else:
            pytest.fail("the observer's e-stop did not disarm the pilot's lease")
    assert shlex.split(pilot_arm)[:3] == ["zenoh", "--config", "pilot.json5"]
