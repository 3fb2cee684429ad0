"""What ROS 2 users reach for first (issue 14): `viena list` (keys, schema, rate), `viena hz`
(rate, jitter, bandwidth), `viena info drive.mcap`, `viena sub --field`. The arithmetic on
made-up arrivals; the commands against the simulated car and a recording."""
from __future__ import annotations

import json

import msgpack
import pytest
from vienatest import viena, wait_for_line

from viena.common.recording import RecordingWriter
from viena.hz import RateMeter
from viena.sub import MISSING, field, select

TRUTH = "viena/elettra/sim/truth"


def test_rate_meter_measures_rate_jitter_and_bandwidth():
    meter = RateMeter(window=5)
    assert meter.rates().rate_hz is None
    for i, t in enumerate([0.0, 0.010, 0.020, 0.031, 0.039, 0.050, 0.060]):
        meter.add(t, 100 + i)
    rates = meter.rates()                          # the last five: 0.020 .. 0.060
    assert rates.samples == 5 and meter.total == 7
    assert rates.rate_hz == pytest.approx(4 / 0.040)
    assert rates.period_s == pytest.approx(0.010)
    assert rates.period_min_s == pytest.approx(0.008) and rates.period_max_s == pytest.approx(0.011)
    assert rates.period_std_s == pytest.approx((1.5e-6) ** 0.5)      # periods 11, 8, 11, 10 ms
    assert rates.bytes_per_s == pytest.approx((103 + 104 + 105 + 106) / 0.040)
    assert rates.bytes_per_sample == pytest.approx(104)
    assert "100.00 Hz" in rates.line() and "B/sample" in rates.line()


def test_field_reaches_inside_a_sample():
    sample = {"accel_mps2": [0.1, 0.2, 9.8], "decision": {"reason": "slew"}, "seq": 3}
    assert field(sample, "accel_mps2") == [0.1, 0.2, 9.8]
    assert field(sample, "accel_mps2.2") == 9.8 and field(sample, "accel_mps2.-1") == 9.8
    assert field(sample, "decision.reason") == "slew"
    assert field(sample, "accel_mps2.3") is MISSING and field(sample, "nope") is MISSING
    assert select(sample, ["seq", "nope"]) == ({"seq": 3}, ["nope"])


def test_info_says_what_a_recording_holds(tmp_path):
    path = tmp_path / "drive.mcap"
    writer = RecordingWriter(path, metadata={"car": "elettra", "host": "viena-pi", "keyexprs": "viena/**",
                                             "started": "2026-05-01T10:12:03+00:00"})
    t0 = 1_777_630_323_000_000_000
    for i in range(201):                           # 2 s of truth at 100 Hz, fixes at 20 Hz
        writer.write(TRUTH, "application/msgpack;viena.sim.truth/1", t0 + i * 10_000_000,
                     msgpack.packb({"t": t0 + i * 10_000_000, "seq": i}))
        if i % 5 == 0:
            writer.write("viena/elettra/gnss/gnss0/fix", "application/msgpack;viena.gnss.fix/1",
                         t0 + i * 10_000_000 + 1, msgpack.packb({"t": 1, "seq": i}))
    writer.close()
    run = viena("info", path)
    assert run.returncode == 0, run.stderr
    out = run.stdout
    assert "complete" in out and "viena-pi" in out and "car elettra" in out
    assert "duration  2.0 s" in out and "samples   242 on 2 keys" in out
    truth_line = next(line for line in out.splitlines() if line.startswith(TRUTH))
    assert truth_line.split()[1:4] == ["viena.sim.truth/1", "201", "100.0"]
    fix_line = next(line for line in out.splitlines() if line.startswith("viena/elettra/gnss/gnss0/fix"))
    assert fix_line.split()[2:4] == ["41", "20.0"]
    as_json = json.loads(viena("info", path, "--json").stdout)
    assert as_json["keys"][TRUTH]["count"] == 201 and as_json["complete"] is True

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    damaged = viena("info", cut)
    assert damaged.returncode == 1 and "INCOMPLETE" in damaged.stdout
    assert f"viena info: {cut}: stopped at byte" in damaged.stderr
    assert viena("info", tmp_path / "none.mcap").returncode == 2


@pytest.fixture
def sim(procs, router, tmp_path):
    config = tmp_path / "sim.toml"
    config.write_text("[sim]\nrate_hz = 100.0\n")
    proc = procs.python("-m", "viena.services.sim.service", "--connect", router, "--config", config)
    wait_for_line(proc.stderr, "started: car elettra")
    return proc


@pytest.mark.slow
def test_list_hz_and_sub_field_on_the_simulated_car(sim, router):
    listed = viena("list", "--connect", router, "--duration", "3", timeout=60)
    assert listed.returncode == 0, listed.stderr
    rows = {line.split()[0]: line.split() for line in listed.stdout.splitlines()}
    assert rows[TRUTH][1] == "viena.sim.truth/1" and 80 < float(rows[TRUTH][2]) < 120
    assert rows["viena/elettra/sim/health"][1] == "viena.health/1"
    assert "alive: sim" in listed.stdout

    hz = viena("hz", TRUTH, "--connect", router, "--duration", "3", timeout=60)
    assert hz.returncode == 0, hz.stderr
    last = hz.stdout.strip().splitlines()[-1]
    assert last.startswith(f"{TRUTH}: ")
    rate = float(last.split(": ", 1)[1].split(" Hz")[0])
    assert 80 < rate < 120 and "period" in last and "std" in last and "kB/s" in last

    sub = viena("sub", TRUTH, "--field", "speed_mps", "--connect", router, "-n", "3", "--timeout", "20")
    assert sub.returncode == 0, sub.stderr
    values = [line.split(" ", 1) for line in sub.stdout.strip().splitlines()]
    assert len(values) == 3 and all(key == TRUTH and float(v) >= 0 for key, v in values)
    two = viena("sub", TRUTH, "--field", "enu_m.0", "--field", "seq", "--json", "--connect", router,
                "-n", "1", "--timeout", "20")
    assert set(json.loads(two.stdout)["value"]) == {"enu_m.0", "seq"}
    wrong = viena("sub", TRUTH, "--field", "sped_mps", "--connect", router, "--timeout", "3")
    assert wrong.stdout == ""
    assert wrong.stderr.count("no field 'sped_mps'") == 1 and "speed_mps" in wrong.stderr
