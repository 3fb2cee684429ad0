"""One program at a time, and a `viena up -d` that tells the truth (issue 14): a program
that stops at a bad setting is reported with its log, not called up; logs, restart,
stop and start by name; an unknown name lists the known ones; a foreground `viena up`
stops everything on SIGTERM, as systemd stops it."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
from contextlib import contextmanager
from pathlib import Path

import pytest
from vienatest import VIENA, sim_profile_up, viena, wait_for_line, wait_until

from viena.common.paths import compose_dir
from viena.profile_security import programs as programs_in

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=9)]  # whole profiles under supervisord


def status(env) -> dict[str, str]:
    out = viena("status", "--profile", "sim", env=env).stdout
    return {line.split()[0]: line.split()[1] for line in out.splitlines() if len(line.split()) > 1}


def pid_of(env, name: str) -> int:
    run = viena("status", "--profile", "sim", env=env)
    lines = [line for line in run.stdout.splitlines() if line.startswith(name + " ")]
    assert len(lines) == 1 and "pid " in lines[0], (name, run.returncode, run.stdout, run.stderr)
    return int(lines[0].split("pid ")[1].split(",")[0])


@pytest.fixture(scope="module")
def profile(tmp_path_factory):
    with sim_profile_up(tmp_path_factory.mktemp("run")) as up:
        yield up


@contextmanager
def edited_sim_profile(tmp_path, name: str, old: str, new: str):
    """A copy of the profiles with `old` replaced by `new` in `name` (sim.toml, sim.conf):
    yields (environment that runs it, the edited file), and brings it down at the end."""
    compose = tmp_path / "compose"
    shutil.copytree(compose_dir(), compose)
    path = compose / name
    path.write_text(path.read_text().replace(old, new, 1))
    env = dict(os.environ, VIENA_RUN=str(tmp_path / "run"), VIENA_COMPOSE=str(compose))
    env.pop("VIENA_ROUTER_PORT", None)
    try:
        yield env, path
    finally:
        viena("down", "--profile", "sim", env=env, timeout=60)


def test_up_detached_reports_a_program_that_stops_at_a_bad_setting(tmp_path):
    with edited_sim_profile(tmp_path, "sim.toml", "[estimator]\n", "[estimator]\nmadgwick_beta = 'fast'\n") as (env, _):
        up = viena("up", "-d", "--free-ports", env=env, timeout=120)
        assert up.returncode == 1, up.stderr
        assert "1 program(s) of profile sim not up:" in up.stderr
        assert "estimator:" in up.stderr and "its log ends:" in up.stderr
        assert "setting 'madgwick_beta' must be float, got 'fast'" in up.stderr
        assert "every program" not in up.stderr
        # supervisord keeps restarting the estimator: on a loaded machine a try may be RUNNING
        # (importing) when looked at, so look until it is caught between two tries
        assert wait_until(lambda: status(env)["estimator"] != "RUNNING", 60, period=0.2)
        assert status(env)["router"] == "RUNNING"


def test_an_unknown_program_lists_the_known_ones(profile):
    env, _ = profile
    known = sorted(programs_in(compose_dir() / "sim.conf"))      # estimator, gnss0, gnss1, razor0, router, ...
    assert {"estimator", "gnss0", "gnss1", "razor0", "router", "sim", "steering"} <= set(known)
    for action in ("logs", "restart", "stop", "start"):
        run = viena(action, "simm", "--profile", "sim", env=env)
        assert run.returncode == 1
        assert run.stderr.strip() == f"viena: no program 'simm' in profile sim (have: {', '.join(known)})"
    follow = viena("logs", "simm", "-f", env=env)
    assert follow.returncode == 1 and "have: " in follow.stderr and "estimator" in follow.stderr


def test_restart_stop_and_start_one_program(profile):
    env, _ = profile
    before = pid_of(env, "gnss1")
    others = {name: pid_of(env, name) for name in ("gnss0", "sim", "router")}
    done = viena("restart", "gnss1", env=env, timeout=90)
    assert done.returncode == 0, done.stderr
    assert "gnss1: running" in done.stdout
    assert pid_of(env, "gnss1") != before
    assert {name: pid_of(env, name) for name in others} == others      # the rest untouched

    stopped = viena("stop", "gnss1", env=env, timeout=60)
    assert stopped.returncode == 0 and status(env)["gnss1"] == "STOPPED"
    started = viena("start", "gnss1", env=env, timeout=90)
    assert started.returncode == 0, started.stderr
    assert status(env)["gnss1"] == "RUNNING"


def test_logs_follows_a_program(profile):
    env, _ = profile
    follow = subprocess.Popen([*VIENA, "logs", "gnss0", "-f"], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        wait_for_line(follow.stdout, "started: car elettra", timeout=20)     # what it said so far
        assert viena("restart", "gnss0", env=env, timeout=90).returncode == 0
        wait_for_line(follow.stdout, "stopped", timeout=30)                  # and what it says next
        wait_for_line(follow.stdout, "started: car elettra", timeout=30)
    finally:
        follow.send_signal(signal.SIGINT)
        follow.wait(timeout=10)


def test_foreground_up_stops_everything_on_sigterm(clean_env):
    """systemd stops the unit by SIGTERM to `viena up` alone (KillMode=mixed)."""
    env = clean_env
    proc = subprocess.Popen([*VIENA, "up", "--free-ports"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    run = Path(env["VIENA_RUN"])
    pids: list[int] = []
    try:
        def supervised() -> bool:
            if not (run / "env.json").exists():
                return False
            out = viena("status", "--profile", "sim", env=env).stdout
            pids[:] = [int(line.split("pid ")[1].split(",")[0]) for line in out.splitlines() if "pid " in line]
            # every program `up` starts (not those it leaves off without --rtk)
            return len(pids) >= len(programs_in(compose_dir() / "sim.conf", {"VIENA_RTK": "false"}))
        assert wait_until(supervised, 60, period=0.2)
        supervisord = int((run / "supervisord.pid").read_text())
        proc.send_signal(signal.SIGTERM)                  # to viena up only, not its group
        assert proc.wait(timeout=30) == 0
        assert "stopping (SIGTERM)" in proc.stderr.read()

        def gone(pid: int) -> bool:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return True
            return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
        assert wait_until(lambda: all(gone(p) for p in [*pids, supervisord]), 10)
        assert json.loads((run / "env.json").read_text())["VIENA_PROFILE"] == "sim"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_a_profile_supervisord_refuses_is_said_in_a_line(tmp_path):
    with edited_sim_profile(tmp_path, "sim.conf", "[program:router]", "[program:router]\nautostart = maybe") \
            as (env, conf):
        up = viena("up", "-d", "--free-ports", env=env, timeout=120)
        assert up.returncode == 1 and "Traceback" not in up.stderr, up.stderr
        assert "maybe" in up.stderr                                     # supervisord's reason
        assert up.stderr.strip().splitlines()[-1] == f"viena: supervisord did not start profile sim ({conf})"
