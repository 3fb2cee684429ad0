"""`viena sim run`: scenario files are checked with one-line errors; a drive in virtual time
gives its summary and report, with every kind of event applied; the same seed gives the
same report and the same recording's bytes; `--seeds` gives a table, a row per seed."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from viena import scenario as scenarios
from viena.cli import main
from viena.common.recording import Recording
from viena.scenario import ScenarioError

#: a short drive that has every kind of event: the pilot starts at about 12 s
EVENTFUL = """
description = "a test drive with one of each event"
duration_s = 30
[sim.gnss0]
outage_interval_s = 0
[[events]]
at_s = 18
kill = "gnss1"
[[events]]
at_s = 20
gnss_outage = "gnss0"
for_s = 2
[[events]]
at_s = 21
imu_bias = "razor0"
gyro_dps = [0.0, 0.0, 0.5]
[[events]]
at_s = 23
flood = "pilot/route"
rate_hz = 50
for_s = 1
bytes = 300
[[events]]
at_s = 27
steering_fault = 0x4210
"""


def test_every_shipped_scenario_parses():
    names = scenarios.shipped()
    assert {"loop", "gnss_outage", "rtk", "imu_faults", "kills"} <= set(names)
    for name in names:
        scenario = scenarios.load(scenarios.resolve(name))
        assert scenario.description and scenario.duration_s > 0
    rtk = scenarios.load(scenarios.resolve("rtk"))
    assert rtk.overrides["sim"]["gnss0"]["cep_m"] == 0.05 and rtk.route is None
    kills = scenarios.load(scenarios.resolve("kills"))
    assert [e.kind for e in kills.events] == ["kill", "kill", "kill", "steering_fault", "flood"]
    assert kills.events[3].options["code"] == 0x4210 and kills.events[3].target == "epos0"


@pytest.mark.parametrize("body, field", [
    ("speed = 3", "speed"),
    ("duration_s = -1", "duration_s"),
    ('route = "nowhere.geojson"', "route"),
    ("[sim]\nspeed_minn_mps = 3", "[sim]"),
    ('[sim.gnss0]\ncep_m = "good"', "[sim.gnss0]"),
    ("[sim.epos0]\nlock = 3", "[sim.epos0]"),
    ("[estimator]\nalign_s = [1]", "[estimator]"),
    ('[[events]]\nkill = "gnss0"', "events[0].at_s"),
    ('[[events]]\nat_s = 3\nkill = "gnss3"', "events[0].kill"),
    ('[[events]]\nat_s = 3\nkill = "gnss0"\nstop = "gnss1"', "events[0]"),
    ('[[events]]\nat_s = 3\ngnss_outage = "gnss0"', "events[0].for_s"),
    ('[[events]]\nat_s = 3\ngnss_outage = "razor0"\nfor_s = 2', "events[0].gnss_outage"),
    ('[[events]]\nat_s = 3\nimu_bias = "razor0"\ngyro_dps = [1, 2]', "events[0].gyro_dps"),
    ("[[events]]\nat_s = 3\nsteering_fault = 0x1234", "events[0].steering_fault"),
    ('[[events]]\nat_s = 3\nflood = "pilot/route"\nrate_hz = 10\nfor_s = 1\nevery = 2', "events[0].every"),
    ("x = [1", None),
])
def test_a_mistake_is_one_line_naming_the_file_and_the_field(tmp_path, body, field):
    path = tmp_path / "bad.toml"
    path.write_text(body + "\n")
    with pytest.raises(ScenarioError) as raised:
        scenarios.load(path)
    message = str(raised.value)
    assert "\n" not in message and message.startswith(f"{path}"), message
    if field is not None:
        assert message.startswith(f"{path}: {field}") or message.startswith(f"{path} {field}"), message


def test_the_command_line_says_what_is_wrong_in_one_line(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text('[[events]]\nat_s = 3\nkill = "gnss3"\n')
    assert main(["sim", "run", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("viena sim run: ") and "events[0].kill" in err and "\n" not in err


@pytest.fixture(scope="module")
def twice(tmp_path_factory):
    """The eventful scenario driven twice with seed 1, in two fresh processes side by side
    (the steering client's setpoint counter is the process's: services/steering/client.py
    next_seq): (stdout, report, recording) each."""
    tmp = tmp_path_factory.mktemp("sim-run")
    path = tmp / "eventful.toml"
    path.write_text(EVENTFUL)
    runs = [subprocess.Popen([sys.executable, "-m", "viena.cli", "sim", "run", str(path), "--seed", "1",
                              "--report", str(tmp / f"r{n}.json"), "--record", str(tmp / f"r{n}.mcap")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for n in (1, 2)]
    done = []
    try:
        for n, run in enumerate(runs, 1):
            out, err = run.communicate(timeout=240)
            assert run.returncode == 0, err
            done.append((out, (tmp / f"r{n}.json").read_text(), tmp / f"r{n}.mcap"))
    finally:
        for run in runs:
            if run.poll() is None:
                run.kill()
                run.wait()
    return done


@pytest.mark.slow
def test_a_drive_says_how_the_pilot_and_the_estimator_did(twice):
    text, report_json, _ = twice[0]
    report = json.loads(report_json)
    assert report["scenario"] == "eventful" and report["seed"] == 1 and report["errors"] == []
    pilot, estimator, steering = report["pilot"], report["estimator"], report["steering"]
    assert pilot["starts"] >= 1 and pilot["following_s"] > 5.0
    assert set(pilot["cross_track_m"]) == {"rms", "p95", "max", "n"} and 0 < pilot["cross_track_m"]["rms"] < 3.0
    assert set(estimator["error_m"]) == {"rms", "p95", "max", "n"} and estimator["error_m"]["n"] > 1000
    assert 0.0 <= estimator["inside_95"] <= 1.0
    assert estimator["gnss_rejected"]["status"] >= 30          # gnss0's 2 s outage at 20 Hz
    # the drive fault at 27 s stops the steering, and the pilot with it, each saying why
    assert any("Over Temperature" in cause for cause in steering["stops"]), steering
    assert any("Over Temperature" in cause for cause in pilot["stops"]), pilot
    done = {e["what"].split()[0]: e["result"] for e in report["events"]}
    assert done == {"kill": "killed", "start": "started", "GNSS": "no fix until 22 s", "bias": "stepped",
                    "flood": "50 puts", "EPOS": "raised"}, report["events"]
    for line in ("pilot ", "cross-track against the truth: RMS", "estimator ", "inside its 95 % ellipse",
                 "resets:", "steering    stops:", "at 18 s: kill gnss1"):
        assert line in text, text


@pytest.mark.slow
def test_the_same_seed_gives_the_same_report_and_the_same_recording(twice):
    (_, first, first_mcap), (_, again, again_mcap) = twice
    assert first == again
    assert first_mcap.read_bytes() == again_mcap.read_bytes()


@pytest.mark.slow
def test_the_recording_is_one_viena_reads(twice):
    recording = Recording(twice[0][2])
    counts: dict[str, int] = {}
    for sample in recording.messages():
        counts[sample.key] = counts.get(sample.key, 0) + 1
    assert recording.problems == [] and not recording.stopped
    assert counts["viena/elettra/sim/truth"] == pytest.approx(100 * 30, abs=2)
    for key in ("estimator/state", "pilot/state", "steering/state", "gnss/gnss0/fix", "imu/razor0/sample",
                "pilot/path", "pilot/route"):
        assert counts.get(f"viena/elettra/{key}", 0) > 0, key


@pytest.mark.slow
def test_seeds_give_a_table_with_a_row_per_seed(tmp_path, capsys):
    report = tmp_path / "seeds.json"
    assert main(["sim", "run", "--seeds", "1..2", "--duration", "12", "--report", str(report)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert [row.split("│")[1].strip() for row in rows] == ["1", "2", "mean", "worst"], out
    data = json.loads(report.read_text())
    assert data["seeds"] == [1, 2] and [r["seed"] for r in data["runs"]] == [1, 2]
    assert set(data["mean"]) == set(data["worst"]) and "estimate_rms_m" in data["mean"]


def test_a_seed_range_is_a_to_b():
    from viena.sim_run import seed_range
    assert seed_range("1..3") == [1, 2, 3]
    with pytest.raises(Exception, match="A..B"):
        seed_range("3..1")

