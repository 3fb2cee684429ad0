"""The habits of a well-kept project, checked with the suite: `scripts/lint` (ruff over the
repository, mypy over viena.common, the drivers, the estimator, the pilot, the GNSS twins and
viena-ntrip, rules in pyproject.toml) finds nothing.
CI runs the same script before the tests, and .pre-commit-config.yaml before each commit."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # two tools in subprocesses: seconds
def test_lint_and_types_find_nothing():
    pytest.importorskip("ruff")
    pytest.importorskip("mypy")
    # the virtualenv this suite runs in, whichever it is; mypy's cache is the one
    # scripts/lint keeps (incremental, checked against the sources: after CI's own lint
    # step, or any lint before, this run takes a few seconds instead of twenty)
    env = {**os.environ, "VIENA_VENV": str(Path(sys.executable).parents[1])}
    result = subprocess.run([str(REPO / "scripts" / "lint")], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
