"""Pi and laptop as two hosts: network namespaces joined by a veth pair.

The "pi" runs the router and the device services with the `pi` profile (pointed at the
simulated car's twins instead of /dev/ttyUSB*), the "laptop" runs the `laptop` profile as
zenoh clients of the Pi's router. The estimator moves between them by editing only the
profiles' [include] lists, and its state reaches the laptop either way; the laptop's
clients also survive a restart of the Pi's router.

Both run as on the car: TLS with the car's certificates and the router's access control.
The keys are made in one place (here the Pi's namespace stands in for the trusted
machine: `viena keys init --router-host <its address>`); the laptop holds only what it
runs with (`viena keys export`), in a key store of its own.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from vienatest import Processes

from viena.common.paths import compose_dir

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=35)]  # two hosts, each with a whole profile

PY = sys.executable
TAG = f"{os.getpid() % 100000}"
PI_ADDR, LAPTOP_ADDR = "10.254.77.1", "10.254.77.2"


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check)


def netns_available() -> str | None:
    """None if this test can make namespaces, else why not."""
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is not installed"
    probe = f"viena-probe-{TAG}"
    made = ip("netns", "add", probe, check=False)
    if made.returncode != 0:
        return f"cannot create network namespaces here: {made.stderr.strip()}"
    ip("netns", "del", probe, check=False)
    return None


class Host:
    """A network namespace standing for one machine."""

    def __init__(self, name: str, workdir: Path):
        self.name = name
        self.keys = workdir / name / "keys"
        self.env = dict(os.environ, VIENA_RUN=str(workdir / name / "run"),
                        VIENA_COMPOSE=str(workdir / "compose"), VIENA_KEYS=str(self.keys))
        for variable in ("VIENA_ROUTER_PORT", "VIENA_LINK", "VIENA_IDENTITY"):
            self.env.pop(variable, None)
        self.processes = Processes()

    def run(self, *cmd: str, timeout: float = 120, **env) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.name, *cmd], env={**self.env, **env},
                              capture_output=True, text=True, timeout=timeout)

    def start(self, *cmd: str, **env) -> subprocess.Popen:
        return self.processes.start("ip", "netns", "exec", self.name, *cmd, env={**self.env, **env})

    def viena(self, *args: str, timeout: float = 120, **env) -> subprocess.CompletedProcess:
        return self.run(PY, "-m", "viena.cli", *args, timeout=timeout, **env)

    def cleanup(self) -> None:
        self.processes.stop_all()
        # whatever is still inside our namespace was started by this test
        left = ip("netns", "pids", self.name, check=False).stdout.split()
        for pid in left:
            try:
                os.kill(int(pid), signal.SIGKILL)
            except (ProcessLookupError, ValueError):
                pass
        ip("netns", "del", self.name, check=False)


@pytest.fixture
def hosts():
    why = netns_available()
    if why:
        pytest.skip(why)
    # a short directory: supervisord's socket path must fit in AF_UNIX's 108 bytes, which
    # tmp_path under a parallel worker (…/popen-gw2/test_estimator_moves_…/) does not leave
    tmp_path = Path(tempfile.mkdtemp(prefix="viena-"))
    shutil.copytree(compose_dir(), tmp_path / "compose")
    pi, laptop = Host(f"viena-pi-{TAG}", tmp_path), Host(f"viena-laptop-{TAG}", tmp_path)
    veth_pi, veth_laptop = f"vpi{TAG}", f"vlt{TAG}"
    try:
        for host in (pi, laptop):
            ip("netns", "add", host.name)
            ip("-n", host.name, "link", "set", "lo", "up")
        ip("link", "add", veth_pi, "type", "veth", "peer", "name", veth_laptop)
        ip("link", "set", veth_pi, "netns", pi.name)
        ip("link", "set", veth_laptop, "netns", laptop.name)
        ip("-n", pi.name, "addr", "add", f"{PI_ADDR}/30", "dev", veth_pi)
        ip("-n", laptop.name, "addr", "add", f"{LAPTOP_ADDR}/30", "dev", veth_laptop)
        ip("-n", pi.name, "link", "set", veth_pi, "up")
        ip("-n", laptop.name, "link", "set", veth_laptop, "up")
        yield pi, laptop, tmp_path
    finally:
        for host in (pi, laptop):
            host.viena("down", "--profile", "pi" if host is pi else "laptop", timeout=60)
            host.cleanup()
        shutil.rmtree(tmp_path, ignore_errors=True)
    assert not any(name in ip("netns", "list").stdout for name in (pi.name, laptop.name))


def move(compose: Path, program: str, src: str, dst: str) -> None:
    """Move a program between two profiles: the only change a placement needs."""
    entry = f"programs/{program}.ini"
    for profile, add in ((src, False), (dst, True)):
        path = compose / f"{profile}.conf"
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            if line.startswith("files ="):
                files = [f for f in line.split("=", 1)[1].split() if f != entry]
                if add:
                    files.append(entry)
                lines[i] = "files = " + " ".join(files)
        path.write_text("\n".join(lines) + "\n")


def sim_device_env() -> dict:
    """Point the pi profile's devices at the simulated car's twins (same namespace)."""
    return {
        "VIENA_GNSS0_DEVICE": "socket://127.0.0.1:5001",
        "VIENA_GNSS1_DEVICE": "socket://127.0.0.1:5002",
        "VIENA_RAZOR0_DEVICE": "socket://127.0.0.1:5003",
        "VIENA_CAN_INTERFACE": "slcan",
        "VIENA_CAN_CHANNEL": "socket://127.0.0.1:5004",
    }


def estimator_states(laptop: Host, count: int, timeout: float = 60, link: str = "tls") -> list[dict]:
    run = laptop.viena("sub", "viena/elettra/estimator/state", "--json", "-n", str(count),
                       "--timeout", str(timeout), "--connect", f"{link}/{PI_ADDR}:7447",
                       timeout=timeout + 30)
    return [json.loads(line)["value"] for line in run.stdout.splitlines() if line.startswith("{")]


def running(host: Host, profile: str) -> dict[str, str]:
    out = host.viena("status", "--profile", profile).stdout
    return {line.split()[0]: line.split()[1] for line in out.splitlines() if len(line.split()) > 1}


@pytest.mark.timeout(600)
def test_estimator_moves_between_laptop_and_pi_by_profile_only(hosts):
    pi, laptop, work = hosts
    compose = work / "compose"
    move(compose, "estimator", "pi", "laptop")                   # start with it on the laptop

    # keys: made on the Pi, the laptop's identities carried over
    made = pi.viena("keys", "init", "--router-host", PI_ADDR)
    assert made.returncode == 0, made.stderr
    carried = pi.viena("keys", "export", "estimator", "observer", "pilot", "-o", str(laptop.keys))
    assert carried.returncode == 0, carried.stderr

    # the Pi: the simulated car stands in for the hardware, then the pi profile
    pi.start(PY, "-m", "viena.services.sim.service", "--config", str(compose / "sim.toml"),
             "--connect", "tls/localhost:7447")
    up = pi.viena("up", "--profile", "pi", "-d", **sim_device_env())
    assert up.returncode == 0, up.stderr
    assert "TLS and access control" in up.stderr
    laptop_env = {"VIENA_PI": PI_ADDR}
    up = laptop.viena("up", "--profile", "laptop", "-d", **laptop_env)
    assert up.returncode == 0, up.stderr
    assert "estimator" in running(laptop, "laptop") and "estimator" not in running(pi, "pi")

    # a recorder on the laptop, as a zenoh client of the Pi's router
    recording = work / "drive.mcap"
    recorder = laptop.start(PY, "-m", "viena.cli", "record", "viena/elettra/**", "-o", str(recording),
                            "-q", "--connect", f"tls/{PI_ADDR}:7447")
    states = estimator_states(laptop, 5)
    assert len(states) == 5 and all(s["t"] > 0 for s in states)

    # across the network: no session without a certificate, no steering without the role
    assert estimator_states(laptop, 1, timeout=5, link="tcp") == []
    config = laptop.viena("keys", "zenoh-config", "observer", "--connect", f"tls/{PI_ADDR}:7447")
    (work / "observer.json5").write_text(config.stdout)
    zenoh_cli = str(Path(PY).parent / "zenoh")
    arm = ["get", "-s", "viena/elettra/steering/arm", "-v", '{"arm": true}', "--decoder", "text"]
    refused = laptop.run(zenoh_cli, "--config", str(work / "observer.json5"), *arm, timeout=30)
    assert refused.returncode == 0 and refused.stdout.strip() == "", refused.stdout + refused.stderr
    config = laptop.viena("keys", "zenoh-config", "pilot", "--connect", f"tls/{PI_ADDR}:7447")
    (work / "pilot.json5").write_text(config.stdout)
    deadline = time.monotonic() + 120        # the steering twin sweeps lock to lock first
    while True:
        armed = laptop.run(zenoh_cli, "--config", str(work / "pilot.json5"), *arm, timeout=30)
        if '"accepted"' in armed.stdout or "calibrating" not in armed.stdout or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert '"status":"accepted"' in armed.stdout.replace(" ", ""), armed.stdout + armed.stderr
    lease = json.loads(armed.stdout.strip().splitlines()[-1])["lease"]
    disarm = ["get", "-s", "viena/elettra/steering/arm", "-v", json.dumps({"arm": False, "lease": lease}),
              "--decoder", "text"]
    assert '"accepted"' in laptop.run(zenoh_cli, "--config", str(work / "pilot.json5"), *disarm).stdout

    # the Pi's router restarts: the laptop's clients reconnect and state flows again
    restart = pi.run(PY, "-m", "supervisor.supervisorctl", "-s",
                     f"unix://{pi.env['VIENA_RUN']}/supervisor.sock", "restart", "router")
    assert "started" in restart.stdout, restart.stdout + restart.stderr
    assert len(estimator_states(laptop, 5)) == 5

    # move the estimator to the Pi: only the profiles change
    laptop.viena("down", "--profile", "laptop")
    move(compose, "estimator", "laptop", "pi")
    update = pi.viena("update", "--profile", "pi")
    assert update.returncode == 0, update.stdout + update.stderr
    assert "estimator" in running(pi, "pi")
    states = estimator_states(laptop, 5)
    assert len(states) == 5

    recorder.send_signal(signal.SIGINT)
    assert recorder.wait(timeout=30) == 0, recorder.stderr.read()
    assert recording.exists() and recording.stat().st_size > 0
