"""The habits of a well-kept project, checked with the suite: the lint and the types.

Both read their configuration from pyproject.toml. mypy runs from outside the repository
on the installed package (`viena.common`, the drivers), so it sees the one import name
the code uses. .pre-commit-config.yaml runs the same two before each commit."""

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: where types are checked: the shared contracts and the code that handles bytes
TYPED = ("viena.common", "viena.services.gnss.driver", "viena.services.imu.driver",
         "viena.services.steering.driver")


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True)


def test_ruff_finds_nothing():
    pytest.importorskip("ruff")
    result = run("ruff", "check", "--no-cache", "--output-format", "concise", ".", cwd=REPO)
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_finds_nothing_in_common_and_the_drivers(tmp_path):
    pytest.importorskip("mypy")
    packages = [arg for name in TYPED for arg in ("-p", name)]
    result = run("mypy", "--config-file", str(REPO / "pyproject.toml"), "--cache-dir", str(tmp_path),
                 "--python-executable", sys.executable, *packages, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
