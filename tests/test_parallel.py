"""scripts/test keeps whole cars to their lanes with pytest-xdist's `--dist loadgroup`
(docs/testing.md#parallel). If an upgrade of pytest or pytest-xdist stops honouring
`xdist_group` marks, as pytest 9.2 did (pytest-dev/pytest-xdist#1386), nothing fails by
itself: cars just run side by side and their watchdogs trip. This says so instead."""
from __future__ import annotations

import subprocess
import sys

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
