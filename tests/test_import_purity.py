"""Contracts and models load no I/O: importing any `model/` module or any schema module, alone
in a fresh interpreter, loads none of serial, can, canopen, pynmea2, zenoh (issue 29). So a
reader of a sample (the estimator, a notebook, a test) needs no driver, and a model stays a
function of its inputs. One interpreter per module: imports accumulate, so a loop in one
process would blame a module for what an earlier one loaded."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
IO_MODULES = ("serial", "can", "canopen", "pynmea2", "zenoh")
#: schema modules outside a model/ room, and the estimator's readers and output
EXPLICIT = ("viena.common.schema", "viena.common.health", "viena.common.json_schema", "viena.common.keys",
            "viena.services.estimator.inputs", "viena.services.estimator.output")
#: a module that declares a schema: `NAME = Schema("viena.<...>/<version>", ...)`
DECLARES_SCHEMA = re.compile(r'^\w+ = Schema\("viena\.', re.M)


def module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(("viena", *(parts[:-1] if parts[-1] == "__init__" else parts)))


def contract_modules() -> list[str]:
    """Every contract (common/samples/) and model module (globbed, so new ones are covered),
    every module under common/ and services/ that declares a schema, and the explicit list."""
    found = {module_name(p) for p in REPO.glob("services/*/model/*.py")}
    found |= {module_name(p) for p in REPO.glob("common/samples/*.py")}
    found |= {module_name(p) for root in ("common", "services") for p in (REPO / root).rglob("*.py")
              if DECLARES_SCHEMA.search(p.read_text())}
    return sorted(found | set(EXPLICIT))


def test_the_list_covers_every_model_and_schema():
    modules = contract_modules()
    assert {f"viena.common.samples.{name}" for name in (
        "fix", "corrections", "ntrip", "imu", "steering", "estimator", "pilot", "truth", "health", "topics")} | {
        "viena.services.imu.model.sample_builder", "viena.services.sim.model.truth",
        "viena.services.steering.model.state", "viena.common.health", "viena.common.samples"} <= set(modules)
    assert len(modules) >= 45


@pytest.mark.parametrize("module", contract_modules())
def test_importing_a_contract_or_model_loads_no_io(module):
    probe = (f"import importlib, sys; importlib.import_module({module!r}); "
             f"print(' '.join(m for m in {IO_MODULES!r} if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == [], f"importing {module} loads {run.stdout.split()}"
