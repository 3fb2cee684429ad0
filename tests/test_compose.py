"""The `sim` profile's life under supervisord: status, logs and down leave nothing behind,
and a foreground `viena up` stops everything on Ctrl-C. (The profile watched with the
`zenoh` CLI and `viena sub`: test_sim_profile.py, on the profile that module runs.)"""
import subprocess
from pathlib import Path

import pytest
from vienatest import VIENA, sim_profile_up, viena, wait_until

from viena.common.runstate import process_alive

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=11)]  # whole profiles under supervisord


@pytest.fixture
def sim_profile(tmp_path):
    with sim_profile_up(tmp_path / "run") as up:
        yield up


def supervised_pids(env) -> list[int]:
    out = viena("status", "--profile", "sim", env=env).stdout
    return [int(line.split("pid ")[1].split(",")[0]) for line in out.splitlines() if "pid " in line]


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
    assert not any(process_alive(pid) for pid in [*pids, supervisord])
    assert viena("status", "--profile", "sim", env=env).returncode == 3


def test_foreground_up_stops_everything_on_ctrl_c(clean_env):
    import signal
    env = clean_env
    proc = subprocess.Popen([*VIENA, "up", "--free-ports"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        run = Path(env["VIENA_RUN"])
        pids = []

        def supervised():
            pids[:] = supervised_pids(env) if (run / "env.json").exists() else []
            return len(pids) >= 2
        wait_until(supervised, 20, period=0.1)
        assert len(pids) >= 2
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
        assert not any(process_alive(pid) for pid in pids)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
