"""Every process's life: flags, config errors, health, liveliness, and a clean stop."""
import signal
import subprocess
import sys
import time

import pytest
from vienatest import collect, wait_for_line, wait_until

from viena.common.samples.health import HEALTH
from viena.common.samples.truth import TRUTH

pytestmark = pytest.mark.slow  # every service is started as a process


def test_help_explains_the_common_flags():
    out = subprocess.run([sys.executable, "-m", "viena.services.sim.service", "--help"],
                         capture_output=True, text=True, check=True).stdout
    for flag in ("--connect ENDPOINT", "--car NAME", "--config FILE"):
        assert flag in out
    # issue 14: --unit only where units exist (one simulated car; several GNSS receivers)
    assert "--unit" not in out
    gnss = subprocess.run([sys.executable, "-m", "viena.services.gnss.service", "--help"],
                          capture_output=True, text=True, check=True).stdout
    assert "--unit NAME" in gnss


@pytest.mark.parametrize("text, message", [
    ("[sim]\nrate_hz = 'fast'\n", "setting 'rate_hz' must be float"),
    ("[sim]\nspeed = 3\n", "unknown setting 'speed'"),
    ("[sim\n", "sim.toml: "),
    ("[zenoh]\nconnect = 5\n", "setting 'connect' must be an endpoint"),
    ("[zenoh]\nconnect = 'tcp/${NOT_SET_ANYWHERE_42}'\n", "NOT_SET_ANYWHERE_42 is not set"),
])
def test_config_error_is_one_line_naming_file_and_setting(tmp_path, text, message):
    path = tmp_path / "sim.toml"
    path.write_text(text)
    run = subprocess.run([sys.executable, "-m", "viena.services.sim.service", "--config", str(path)],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert str(path) in lines[0] and message in lines[0]
    assert "Traceback" not in run.stderr


def test_missing_config_file(tmp_path):
    run = subprocess.run([sys.executable, "-m", "viena.services.sim.service", "--config",
                          str(tmp_path / "nope.toml")], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "nope.toml: no such file" in run.stderr


def start_sim(procs, router, *extra):
    return procs.python("-m", "viena.services.sim.service", "--connect", router, *extra)


def test_service_publishes_health_and_a_liveliness_token(procs, router, session):
    start_sim(procs, router)
    health = collect(session, "viena/elettra/sim/health", 2, timeout=15, decode=HEALTH.decode)
    assert len(health) == 2
    assert health[1]["service"] == "sim"
    assert health[1]["counts"]["truth"] > 0
    assert health[1]["last_sample_age_s"] is not None and health[1]["last_sample_age_s"] < 1.0
    tokens = [str(r.ok.key_expr) for r in session.liveliness().get("viena/elettra/alive/**", timeout=5) if r.ok]
    assert "viena/elettra/alive/sim" in tokens


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_stops_within_two_seconds_with_status_zero(procs, router, session, sig):
    proc = start_sim(procs, router, "--car", "stoptest")
    assert collect(session, "viena/stoptest/sim/truth", 5, timeout=15)
    sent = time.monotonic()
    proc.send_signal(sig)
    status = proc.wait(timeout=10)
    took = time.monotonic() - sent
    assert status == 0, proc.stderr.read()
    assert took < 2.0, f"stopped in {took:.2f} s"
    err = proc.stderr.read()
    assert "stopped" in err and "exiting anyway" not in err
    # and the token is gone with it (once the router has seen the session end)
    def tokens():
        return [r for r in session.liveliness().get("viena/stoptest/alive/**", timeout=2) if r.ok]
    wait_until(lambda: tokens() == [], 5, period=0.05)
    assert tokens() == []


def test_service_waits_for_a_router_that_comes_later(procs, tmp_path):
    import zenoh
    from vienatest import free_port, wait_for_port

    from viena.common.config import load_zenoh_config

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    sim = start_sim(procs, endpoint)
    wait_for_line(sim.stderr, "cannot reach the router yet")
    assert sim.poll() is None                      # still trying, not dead
    procs.python("-m", "viena.router", "--listen", endpoint)
    wait_for_port(port)
    with zenoh.open(load_zenoh_config(mode="client", connect=[endpoint])) as s:
        got = collect(s, "viena/elettra/sim/truth", 3, timeout=15, decode=TRUTH.decode)
    assert len(got) == 3
