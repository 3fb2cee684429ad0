"""The `sim` profile under supervisord, watched with the real `zenoh` CLI and `viena sub`."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

VIENA = [sys.executable, "-m", "viena.cli"]
ZENOH_CLI = shutil.which("zenoh", path=str(Path(sys.executable).parent)) or shutil.which("zenoh")


def viena(*args, env, timeout=60):
    return subprocess.run([*VIENA, *args], env=env, capture_output=True, text=True, timeout=timeout)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is gone for our purposes
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except FileNotFoundError:
        return False


@pytest.fixture
def sim_profile(clean_env):
    env = clean_env
    up = viena("up", "--profile", "sim", "-d", "--free-ports", env=env)
    assert up.returncode == 0, up.stderr
    run = Path(env["VIENA_RUN"])
    saved = json.loads((run / "env.json").read_text())
    try:
        yield env, f"tcp/127.0.0.1:{saved['VIENA_ROUTER_PORT']}"
    finally:
        viena("down", "--profile", "sim", env=env)


def supervised_pids(env) -> list[int]:
    out = viena("status", "--profile", "sim", env=env).stdout
    return [int(line.split("pid ")[1].split(",")[0]) for line in out.splitlines() if "pid " in line]


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
    import msgpack
    import zenoh
    from vienatest import collect
    from viena.common.config import load_zenoh_config

    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as s:
        import threading
        got = []
        t = threading.Thread(target=lambda: got.extend(collect(s, "viena/elettra/test/put", 1, timeout=20)))
        t.start()
        import time
        time.sleep(1.0)
        subprocess.run([ZENOH_CLI, "--mode", "client", "--connect", router, "--cfg",
                        "scouting/multicast/enabled:false", "put", "-k", "viena/elettra/test/put",
                        "--encoder", "msgpack", "-v", '{"a": 1}'], check=True, timeout=30)
        t.join()
    assert got and msgpack.unpackb(got[0][1]) == {"a": 1}


def test_status_logs_and_down_leave_nothing_behind(sim_profile):
    env, _router = sim_profile
    status = viena("status", "--profile", "sim", env=env)
    assert "router" in status.stdout and "RUNNING" in status.stdout
    pids = supervised_pids(env)
    assert len(pids) >= 2
    supervisord = int((Path(env["VIENA_RUN"]) / "supervisord.pid").read_text())
    logs = viena("logs", "sim", "--profile", "sim", env=env)
    assert "started: car elettra" in logs.stdout
    down = viena("down", "--profile", "sim", env=env)
    assert down.returncode == 0, down.stderr
    assert not any(alive(pid) for pid in [*pids, supervisord])
    assert viena("status", "--profile", "sim", env=env).returncode == 3


def test_foreground_up_stops_everything_on_ctrl_c(clean_env):
    import signal
    import time
    env = clean_env
    proc = subprocess.Popen([*VIENA, "up", "--free-ports"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        run = Path(env["VIENA_RUN"])
        deadline = time.monotonic() + 20
        pids = []
        while time.monotonic() < deadline and len(pids) < 2:
            time.sleep(0.3)
            if (run / "env.json").exists():
                pids = supervised_pids(env)
        assert len(pids) >= 2
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
        assert not any(alive(pid) for pid in pids)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
