"""scripts/test keeps whole cars to their lanes with pytest-xdist's `--dist loadgroup`
(docs/testing.md#parallel). If an upgrade of pytest or pytest-xdist stops honouring
`xdist_group` marks, as pytest 9.2 did (pytest-dev/pytest-xdist#1386), nothing fails by
itself: cars just run side by side and their watchdogs trip. This says so instead, and
checks that a worker's CPU priority reaches the cars it starts (tests/priority.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # a pytest run of its own, on two workers; processes

GROUPED_AND_FREE = '''
import pytest

@pytest.mark.xdist_group("lane")
@pytest.mark.parametrize("i", range(6))
def test_in_the_lane(i):
    pass

@pytest.mark.parametrize("i", range(6))
def test_free(i):
    pass
'''


def test_a_group_runs_on_one_worker(tmp_path):
    (tmp_path / "test_groups.py").write_text(GROUPED_AND_FREE)
    run = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v",
                          "-p", "no:cacheprovider", "test_groups.py"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    passed = [line.split() for line in run.stdout.splitlines() if " PASSED " in line]
    in_lane = {words[0] for words in passed if "test_in_the_lane" in words[-1]}
    assert len(passed) == 12
    assert len(in_lane) == 1, in_lane            # one worker, e.g. {"[gw0]"}


PRIORITY_PROBE = '''
import os, subprocess, sys
sys.path.insert(0, sys.argv[1])
from priority import WorkerPriority
from vienatest import wait_until

def autogroup_nice(pid):
    return int(open(f"/proc/{pid}/autogroup").read().split()[-1])

worker = WorkerPriority("probe")
worker.lower_to(5)
env = dict(os.environ, PYTEST_XDIST_WORKER="probe")
car = subprocess.Popen(["sleep", "30"], env=env, start_new_session=True)   # as supervisord does
try:
    wait_until(lambda: autogroup_nice(car.pid) == 5, 5.0)
    print(os.getsid(0) == os.getpid(), os.nice(0), autogroup_nice(os.getpid()), autogroup_nice(car.pid))
finally:
    car.kill()
'''


def test_a_worker_and_the_sessions_it_starts_take_its_priority():
    """tests/priority.py: with autogroups, nice alone would not hold a car back."""
    if not os.path.exists("/proc/self/autogroup"):
        pytest.skip("this kernel has no autogroups: plain nice does the job")
    run = subprocess.run([sys.executable, "-c", PRIORITY_PROBE, str(Path(__file__).parent)],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["True", "5", "5", "5"], run.stdout
