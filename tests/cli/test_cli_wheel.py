"""viena installed from a built wheel, as on the Pi (issue 14): no checkout, no test
extras, run from a directory that is not the repository. The profiles, zenoh configs, the
EDS and the shipped recordings must come with the package: `viena up` brings the sim
profile up, `viena router` starts from its packaged config, the GNSS twin replays the
2016 drive, the laptop's tools (sub, list, hz, monitor, doctor) work on the profile, and
a recording made there is read and replayed.

It builds the wheel (`pip wheel`) and installs it into a fresh virtualenv with pip's
ordinary client (the package index and pip's cache: a minute the first time), once for all
the workers of a parallel run: the tests without a car build it on another worker while the
car lane runs, and the one that brings the car up finds it there."""
from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from vienatest import Processes, free_port, wait_for_line, wait_for_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

REPO = Path(__file__).resolve().parents[2]
TRUTH = "viena/elettra/sim/truth"
#: what the test extras add: none of it belongs on the car
TEST_ONLY = ("pytest", "hypothesis", "scipy", "ahrs", "jedi")


def outside_the_checkout(venv: Path) -> dict:
    """The environment of a machine with viena installed in `venv` and no checkout."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "VIENA_COMPOSE", "VIENA_ROUTER_PORT",
                        "VIENA_SETTINGS", "VIENA_PYTHON", "VIENA_CONNECT")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"
    return env


class Installed:
    """A virtualenv holding viena from its wheel, and a directory outside the repository
    to run it in."""

    def __init__(self, root: Path, mine: Path):
        self.root = root
        self.venv = root / "venv"
        self.work = mine / "elsewhere"         # a worker's own: tests on two workers at once
        self.work.mkdir()
        self.run_dir = mine / "run"
        self.env = outside_the_checkout(self.venv)
        self.env["VIENA_RUN"] = str(self.run_dir)
        self.python = str(self.venv / "bin" / "python")

    def run(self, *args, timeout: float = 120) -> subprocess.CompletedProcess:
        return subprocess.run([str(a) for a in args], cwd=self.work, env=self.env, capture_output=True,
                              text=True, timeout=timeout)

    def viena(self, *args, timeout: float = 120) -> subprocess.CompletedProcess:
        return self.run(self.venv / "bin" / "viena", *args, timeout=timeout)

    def popen(self, procs: Processes, *args) -> subprocess.Popen:
        """Started by `procs`, which kills it at the end of the test if it is still there."""
        return procs.start(*args, cwd=self.work, env=self.env)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent                 # the run's, above each worker's own
    root = shared / "wheel"
    with open(shared / "wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)       # one builds, the others wait and use it
        if not (root / "installed").exists():
            install(root)
            (root / "installed").touch()
    return Installed(root, tmp_path_factory.mktemp("wheel-user"))


def install(root: Path) -> None:
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", root / "dist", REPO],
                           capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr
    [wheel] = (root / "dist").glob("viena-*.whl")
    python = root / "venv" / "bin" / "python"
    subprocess.run([sys.executable, "-m", "venv", root / "venv"], check=True, timeout=300)
    pip = subprocess.run([python, "-m", "pip", "install", "-q", wheel], cwd=root, capture_output=True,
                         text=True, timeout=900, env=outside_the_checkout(root / "venv"))
    assert pip.returncode == 0, pip.stderr


def test_it_is_the_wheel_and_only_what_the_car_runs(installed):
    where = installed.run(installed.python, "-c", "import viena, viena.services; print(viena.__file__)")
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()).is_relative_to(installed.venv), where.stdout
    listed = installed.run(installed.python, "-m", "pip", "list", "--format", "json")
    names = {p["name"].lower() for p in json.loads(listed.stdout)}
    assert {"viena", "eclipse-zenoh", "supervisor", "canopen"} <= names
    assert not names & set(TEST_ONLY), names & set(TEST_ONLY)
    version = installed.viena("--version")
    assert version.returncode == 0 and version.stdout.startswith("viena 0.")


def test_every_profile_and_the_steering_eds_are_there(installed):
    for profile in ("sim", "pi", "laptop"):
        status = installed.viena("status", "--profile", profile)
        assert (status.returncode, status.stdout.strip()) == (3, f"profile '{profile}' is down"), status
        unit = installed.viena("service", "show", "--profile", profile)
        assert unit.returncode == 0 and f"up --profile {profile}" in unit.stdout, unit.stderr
    eds = installed.run(installed.python, "-c", "from viena.services.steering.driver.epos import EDS_PATH; "
                        "print(EDS_PATH.stat().st_size)")
    assert eds.returncode == 0 and int(eds.stdout) > 10_000, eds.stderr


def test_router_starts_from_its_packaged_config(installed, procs):
    port = free_port()
    router = installed.popen(procs, installed.venv / "bin" / "viena", "router", "--listen", f"tcp/127.0.0.1:{port}")
    try:
        wait_for_port(port, timeout=30)
        assert router.poll() is None
    finally:
        router.send_signal(signal.SIGTERM)
        router.wait(timeout=20)
    assert "Traceback" not in router.stderr.read()


def test_gnss_twin_replays_the_shipped_drive(installed, procs):
    twin = installed.popen(procs, installed.python, "-m", "viena.services.gnss.simulator", "--replay", "drive")
    try:
        assert wait_for_line(twin.stdout, "READY", timeout=60).startswith("READY socket://")
    finally:
        twin.send_signal(signal.SIGTERM)
        twin.wait(timeout=20)
    assert "Traceback" not in twin.stderr.read()


@pytest.mark.car(seconds=30)
def test_sim_profile_up_and_every_tool_on_it(installed):
    up = installed.viena("up", "-d", "--free-ports", timeout=180)
    try:
        assert up.returncode == 0, up.stderr
        assert "every program of sim is up" in up.stderr
        env = json.loads((installed.run_dir / "env.json").read_text())
        assert env["VIENA_PYTHON"] == installed.python and Path(env["VIENA_SETTINGS"]).is_relative_to(installed.venv)
        wait_for_port(int(env["VIENA_ROUTER_PORT"]), timeout=30)

        sub = installed.viena("sub", TRUTH, "-n", "2", "--timeout", "60")       # the port from env.json
        assert sub.returncode == 0, sub.stderr
        assert [line.split(" ", 1)[0] for line in sub.stdout.strip().splitlines()] == [TRUTH, TRUTH]

        listed = installed.viena("list", "--duration", "2")
        assert listed.returncode == 0 and re.search(f"^{TRUTH} +viena.sim.truth/1 ", listed.stdout, re.M), listed
        hz = installed.viena("hz", TRUTH, "--duration", "2")
        assert hz.returncode == 0 and f"{TRUTH}: " in hz.stdout, hz.stderr
        monitor = installed.viena("monitor", "--duration", "3")
        assert monitor.returncode == 0 and "simulator truth" in monitor.stdout, monitor.stderr
        doctor = installed.viena("doctor")
        assert doctor.returncode == 0 and re.search(r"^OK +programs: \d+ running(, caster, ntrip, recorder off)?$", doctor.stdout, re.M), doctor.stdout

        record = installed.viena("record", TRUTH, "-o", "drive.mcap", "--duration", "2", "-q", timeout=120)
        assert record.returncode == 0, record.stderr
        assert (installed.work / "drive.mcap").exists()
        info = installed.viena("info", "drive.mcap")
        assert info.returncode == 0 and TRUTH in info.stdout, info.stderr

        replay = installed.viena("replay", "drive.mcap", "--car", "replayed", "--timeout", "60", timeout=120)
        assert replay.returncode == 0, replay.stderr
        assert "replayed " in replay.stderr and " samples on 1 keys" in replay.stderr
    finally:
        down = installed.viena("down", timeout=120)
        assert down.returncode == 0, down.stderr
