"""`viena export` and `viena plot` on a drive made offline from the simulated car."""
from __future__ import annotations

import csv
import json
import math

import msgpack
import numpy as np
import pytest
from laptop_helpers import TRUTH_KEY, viena, write_drive, yaw_deg

from viena.common.recording import Recording, RecordingWriter
from viena.export import flatten
from viena.plot import load_drive

FIX_KEY = "viena/elettra/gnss/gnss0/fix"


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    return path, write_drive(path, seconds=20.0)


def test_flatten_names_nested_fields_with_dots():
    value = {"t": 1, "ecef_m": [1.5, 2.0, 3.25], "raw": {"accel_g": [0.0, 1.0]}, "mag_T": None,
             "ok": True, "rates_hz": {"truth": 100.0}}
    assert dict(flatten(value)) == {"t": 1, "ecef_m.0": "1.5", "ecef_m.1": "2.0", "ecef_m.2": "3.25",
                                    "raw.accel_g.0": "0.0", "raw.accel_g.1": "1.0", "mag_T": "",
                                    "ok": True, "rates_hz.truth": "100.0"}


def test_export_csv_one_file_per_key_with_every_value(drive, tmp_path):
    path, written = drive
    result = viena("export", path, "--csv", tmp_path / "csv")
    assert result.returncode == 0, result.stderr
    files = sorted(p.name for p in (tmp_path / "csv").iterdir())
    assert files == sorted(key.replace("/", ".") + ".csv" for key in written)

    with open(tmp_path / "csv" / "viena.elettra.gnss.gnss0.fix.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    fixes = written[FIX_KEY]
    assert len(rows) == len(fixes)
    assert list(rows[0])[:4] == ["log_time_ns", "publish_time_ns", "t", "seq"]
    for row, fix in zip(rows, fixes):
        assert [float(row[f"ecef_m.{i}"]) for i in range(3)] == fix["ecef_m"]   # every digit
        assert int(row["publish_time_ns"]) == fix["t"] == int(row["t"])
        assert int(row["log_time_ns"]) == fix["t"] + 2_000_000
        assert row["diff_age_s"] == ""                                         # None
        assert row["valid"] == str(fix["valid"])

    with open(tmp_path / "csv" / "viena.elettra.sim.truth.csv", newline="") as f:
        truth_rows = list(csv.DictReader(f))
    assert len(truth_rows) == len(written[TRUTH_KEY])
    assert float(truth_rows[-1]["quat.3"]) == written[TRUTH_KEY][-1]["quat"][3]


def test_export_json_lines(drive, tmp_path):
    path, written = drive
    out = tmp_path / "drive.jsonl"
    result = viena("export", path, "--json", out, "--keyexpr", "viena/elettra/steering/**")
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    states = written["viena/elettra/steering/state"]
    assert [line["value"] for line in lines] == states
    assert {line["key"] for line in lines} == {"viena/elettra/steering/state"}
    assert {line["schema"] for line in lines} == {"viena.steering.state/1"}

    to_stdout = viena("export", path, "--json", "--keyexpr", FIX_KEY)
    assert len(to_stdout.stdout.splitlines()) == len(written[FIX_KEY])


def test_export_keeps_fields_that_come_and_go_and_skips_garbage(tmp_path):
    path = tmp_path / "mixed.mcap"
    writer = RecordingWriter(path)
    key, enc = "viena/elettra/x/y", "application/msgpack;viena.x/1"
    writer.write(key, enc, 1, msgpack.packb({"t": 1, "a": 1.0}))
    writer.write(key, enc, 2, b"\xc1 not msgpack")
    writer.write(key, enc, 3, msgpack.packb({"t": 3, "b": [1, 2], "a": float("nan")}))
    writer.write("viena/elettra/typed", "application/json", 4, b'{"text": "from a person"}')
    writer.close()
    result = viena("export", path, "--csv", tmp_path / "out")
    assert result.returncode == 0
    assert "1 undecodable samples on viena/elettra/x/y skipped" in result.stderr
    with open(tmp_path / "out" / "viena.elettra.x.y.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows == [
        {"log_time_ns": "1", "publish_time_ns": "1", "t": "1", "a": "1.0", "b.0": "", "b.1": ""},
        {"log_time_ns": "3", "publish_time_ns": "3", "t": "3", "a": "", "b.0": "1", "b.1": "2"}]
    typed = (tmp_path / "out" / "viena.elettra.typed.csv").read_text().splitlines()
    assert typed[1].endswith(",from a person")


def test_plot_model_puts_every_source_on_one_map(drive):
    path, written = drive
    model = load_drive(Recording(path))
    truth = written[TRUTH_KEY]
    assert model.origin == tuple(truth[0]["origin"]) and model.origin_source == "simulator origin"
    # ECEF -> local ENU through pymap3d lands on the simulator's own ENU within a millimetre
    _, enu = model.truth["enu"].array()
    assert np.abs(enu - np.array([s["enu_m"] for s in truth])).max() < 1e-3
    fixes = [f for f in written[FIX_KEY] if f["valid"]]
    _, gnss = model.gnss["gnss0"]["enu"].array()
    assert len(gnss) == len(fixes) and model.invalid_fixes == len(written[FIX_KEY]) - len(fixes)
    truth_xy = enu[::10][:, :2]
    near = [np.min(np.hypot(*(truth_xy - p[:2]).T)) for p in gnss]
    assert np.median(near) < 3.0                                # 1 m noise, 1.8 m lever arm
    _, est = model.estimator["enu"].array()
    assert len(est) == len(written["viena/elettra/estimator/state"])
    _, sigma = model.estimator["sigma"].array()                 # state/2's sigma_h_m, sigma_v_m
    assert sigma.tolist() == [[0.2, 0.3]] * len(est)
    t, yaw = model.truth["yaw"].array()
    assert yaw[-1] == pytest.approx(yaw_deg(truth[-1]["euler_rad"][0]))
    assert t[0] == 0.0 and t[-1] == pytest.approx(19.99)
    assert set(model.steering) == {"angle", "target", "goal"}
    _, wheel = model.steering["angle"].array()
    assert wheel.max() == pytest.approx(math.degrees(max(s["wheel_angle_rad"] for s in truth)))


@pytest.mark.slow  # matplotlib draws a whole drive
def test_plot_writes_a_png(drive, tmp_path):
    import matplotlib.image

    path, _ = drive
    out = tmp_path / "drive.png"
    result = viena("plot", path, "-o", out)
    assert result.returncode == 0, result.stderr
    image = matplotlib.image.imread(out)
    assert image.shape[0] >= 600 and image.shape[1] >= 1000
    assert image[..., :3].std() > 0.05                           # not a blank canvas


def test_plot_of_a_recording_with_nothing_to_draw(tmp_path):
    path = tmp_path / "health-only.mcap"
    writer = RecordingWriter(path)
    writer.write("viena/elettra/sim/health", "application/msgpack;viena.health/1", 1,
                 msgpack.packb({"t": 1, "seq": 1}))
    writer.close()
    result = viena("plot", path, "-o", tmp_path / "x.png")
    assert result.returncode == 1
    assert "nothing to plot" in result.stderr
    assert not (tmp_path / "x.png").exists()
