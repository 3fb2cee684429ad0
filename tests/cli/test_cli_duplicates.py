"""A second process with the name of a running one (a second `viena-gnss` without --unit)
is refused at start, in one line, found by its liveliness token (issue 14); a process of
another name or another car is not."""
from __future__ import annotations

import pytest
from vienatest import wait_for_line

pytestmark = pytest.mark.slow  # services as processes


def start(procs, router, module: str, *extra):
    return procs.python("-m", f"viena.services.{module}.service", "--connect", router, *extra)


def refusal(proc) -> str:
    assert proc.wait(timeout=30) == 2
    err = proc.stderr.read()
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_a_second_sim_is_refused(procs, router):
    first = start(procs, router, "sim")
    wait_for_line(first.stderr, "started: car elettra")
    line = refusal(start(procs, router, "sim"))
    assert line == ("viena-sim: sim already runs on car elettra (viena/elettra/alive/sim is alive): "
                    "stop that one first")
    other_car = start(procs, router, "sim", "--car", "other")
    wait_for_line(other_car.stderr, "started: car other")
    assert first.poll() is None and other_car.poll() is None


def test_a_second_gnss0_is_refused_and_told_about_unit(procs, router):
    port = ("--port", "socket://127.0.0.1:9")           # no receiver needed to be refused
    first = start(procs, router, "gnss", *port)
    wait_for_line(first.stderr, "started: car elettra, unit gnss0")
    line = refusal(start(procs, router, "gnss", *port))
    assert "gnss0 already runs on car elettra" in line and "another --unit" in line
    second = start(procs, router, "gnss", "--unit", "gnss1", *port)
    wait_for_line(second.stderr, "started: car elettra, unit gnss1")
