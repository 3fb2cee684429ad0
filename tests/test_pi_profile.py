"""The pi profile itself, as `viena bench pi` runs it (benchmarks/pi.py): `viena up --profile
pi` with its TLS, access control and black box, the device services on the twins' serial
and CAN paths, the Foxglove bridge, a pilot steering at 50 Hz. What holds on any machine is
checked here (every key of the car flows, setpoints are answered, each program is measured);
the figures against the Pi's budget are the benchmark's to print, not a test's to assert."""
from __future__ import annotations

import json

import pytest

from benchmarks import pi

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=60)]

PI_PROGRAMS = {"router", "recorder", "gnss0", "gnss1", "razor0", "steering", "estimator", "foxglove"}
STREAMS = {"gnss/gnss0/fix", "gnss/gnss1/fix", "imu/razor0/sample", "steering/state", "estimator/state"}


def test_the_pi_profile_runs_on_the_twins_and_is_measured(capsys):
    assert pi.main(["--seconds", "4", "--warmup", "2", "--cores", "2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["programs"]) == PI_PROGRAMS
    assert all(p["rss_mb"] > 0 and 0 < p["pss_mb"] <= p["rss_mb"] and p["cpu_core_share"] >= 0
               for p in report["programs"].values())
    rates = report["rates"]
    assert STREAMS <= set(rates), rates
    assert all(rates[key]["measured_hz"] > 0 and rates[key]["nominal_hz"] for key in STREAMS)
    assert {f"{name}/health" for name in ("recorder", "steering", "estimator")} <= set(rates)
    assert report["setpoint_round_trip_ms"]["n"] > 0 and report["setpoint_errors"] == []
    assert report["recorder_mb_per_h"] > 0 and report["foxglove_frames"] > 0
