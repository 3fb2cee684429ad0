"""When is a program of a profile up (viena/programs.py `wait_settled`, behind `viena up -d`,
`restart` and `start`)? Against a made-up supervisord on a test clock: a program that is
RUNNING but still importing, silent, and then exits at a bad setting is not up, however
long it took (measured: 14.7 s on a busy machine); one that speaks and stays is up
SETTLE_S after its first word; a program that never speaks is trusted after QUIET_S."""
from __future__ import annotations

import types

import pytest

from viena import programs


class Clock:
    def __init__(self):
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, dt: float) -> None:
        self.now += dt


class Supervisor:
    """getAllProcessInfo from a script: name -> [(from_t, state, start), ...]; and log
    lines written at given times (name -> [(t, line), ...])."""

    def __init__(self, clock: Clock, run_dir, script: dict, says: dict):
        self.clock, self.run_dir, self.script, self.says = clock, run_dir, script, says

    def getAllConfigInfo(self):
        return [{"name": name, "autostart": True} for name in self.script]

    def getAllProcessInfo(self):
        infos = []
        for name, steps in self.script.items():
            with (self.run_dir / f"{name}.log").open("w") as log:
                log.writelines(line + "\n" for t, line in self.says.get(name, []) if t <= self.clock.now)
            _, state, start = [step for step in steps if step[0] <= self.clock.now][-1]
            infos.append({"name": name, "statename": state, "start": start,
                          "exitstatus": 2 if state in ("EXITED", "BACKOFF") else 0})
        return infos


@pytest.fixture
def supervised(tmp_path, monkeypatch):
    monkeypatch.setenv("VIENA_RUN", str(tmp_path))
    clock = Clock()
    monkeypatch.setattr(programs, "time", types.SimpleNamespace(monotonic=clock.monotonic, sleep=clock.sleep))

    def run(script: dict, says: dict) -> list[programs.Failure]:
        fake = Supervisor(clock, tmp_path, script, says)
        monkeypatch.setattr(programs, "rpc", lambda profile: fake)
        before = {name: 0 for name in script}
        return programs.wait_settled("sim", said_before=before)
    return clock, run


def test_a_slow_starter_that_exits_at_a_bad_setting_is_not_up(supervised):
    clock, run = supervised
    error = "viena-estimator: config error: sim.toml [estimator]: setting 'madgwick_beta' must be float"
    failures = run(
        {"router": [(0.0, "STARTING", 0), (1.0, "RUNNING", 0)],
         "estimator": [(0.0, "STARTING", 0), (1.0, "RUNNING", 0),           # importing, silent
                       (14.7, "EXITED", 0), (15.7, "STARTING", 15), (16.7, "RUNNING", 15)]},
        {"router": [(1.5, "router listening on tcp/127.0.0.1:7447")],
         "estimator": [(14.7, error)]})
    [failure] = failures
    assert failure.name == "estimator" and failure.state == "EXITED" and failure.exitstatus == 2
    assert failure.lines == [error]
    assert clock.now < 20


def test_a_program_that_speaks_and_stays_is_up_soon_after(supervised):
    clock, run = supervised
    assert run({"gnss0": [(0.0, "STARTING", 0), (1.0, "RUNNING", 0)]},
               {"gnss0": [(3.0, "started: car elettra, unit gnss0")]}) == []
    assert 3.0 + programs.SETTLE_S <= clock.now < 3.0 + programs.SETTLE_S + 0.5


def test_a_restart_between_two_looks_is_seen(supervised):
    _, run = supervised
    [failure] = run({"gnss0": [(0.0, "RUNNING", 0), (0.95, "RUNNING", 1)]},
                    {"gnss0": [(0.5, "started"), (0.9, "error: no such device")]})
    assert failure.state.startswith("restarted")


def test_a_silent_program_is_trusted_after_quiet_s(supervised):
    clock, run = supervised
    assert run({"other": [(0.0, "STARTING", 0), (1.0, "RUNNING", 0)]}, {}) == []
    assert 1.0 + programs.QUIET_S <= clock.now < 1.0 + programs.QUIET_S + 0.5
