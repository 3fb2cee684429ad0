"""The car's real drive of 2016-06-01 replayed by the NovAtel twin as binary BESTXYZ, and
decoded by the driver epoch by epoch equal to the recording."""
from __future__ import annotations

import calendar
import filecmp
from datetime import datetime

import numpy as np
import pytest
from gnss_helpers import SHARED_CSV, TwinHarness, read_csv, start_twin

from viena.services.gnss.driver.novatel import (
    Log,
    MessageId,
    NovatelReceiver,
    StartupConfig,
    Trigger,
)
from viena.services.gnss.fixes import fix_from_bestxyz
from viena.services.gnss.simulator import DRIVE_CSV, NovatelTwin, load_drive

ROWS = read_csv()
f32 = np.float32


def recorded_utc_s(row) -> float:
    """The logger's clock was Lisbon summer time (UTC+1)."""
    stamp = datetime.strptime(row["Time"], "%Y-%m-%d %H:%M:%S.%f")
    return calendar.timegm(stamp.timetuple()) - 3600 + stamp.microsecond / 1e6


def assert_epoch_equals_row(msg, row):
    d = msg.data
    assert d.pos_status == int(row["PSolStatus"]) and d.vel_status == int(row["VSolStatus"])
    assert d.position_m == (float(row["X"]), float(row["Y"]), float(row["Z"]))
    assert d.velocity_mps == (float(row["VX"]), float(row["VY"]), float(row["VZ"]))
    assert d.position_sigma_m == tuple(float(f32(row[k])) for k in ("stdX", "stdY", "stdZ"))
    assert d.velocity_sigma_mps == tuple(float(f32(row[k])) for k in ("stdVX", "stdVY", "stdVZ"))
    assert d.vel_latency_s == float(f32(row["VLatency"]))
    assert d.sol_age_s == float(f32(row["SolAge"]))
    assert d.sats_used == int(row["SolSatNumber"])
    # the receiver's epoch is 100 ms-aligned GPS time, 20-40 ms before the logger's clock
    lag = recorded_utc_s(row) - msg.utc_ns / 1e9
    assert 0.0 <= lag < 0.1
    assert msg.gps_ms % 100 == 0


@pytest.mark.skipif(not SHARED_CSV.exists(), reason="the original recording is not beside the repository")
def test_the_shipped_recording_is_the_cars():
    assert filecmp.cmp(DRIVE_CSV, SHARED_CSV, shallow=False)
    assert len(ROWS) == 7634
    assert sum(r["PSolStatus"] == "1" for r in ROWS) == 130


def test_whole_drive_decodes_epoch_by_epoch_equal_to_the_csv():
    twin = NovatelTwin(replay=load_drive(), replay_retime=False, replay_speed=50.0)
    h = TwinHarness(twin)
    assert h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05)).ok
    h.run(764.0 / 50.0 + 1.0)
    assert len(h.logs) == len(ROWS)
    assert h.decoder.stats.crc_errors == 0
    for msg, row in zip(h.logs, ROWS):
        assert_epoch_equals_row(msg, row)
    assert h.logs[0].gps_week == 1899                 # 2016-06-01 is in GPS week 1899
    fixes = [fix_from_bestxyz(m, "gnss0", 0) for m in h.logs]
    assert sum(not f["valid"] for f in fixes) == 130
    assert {f["pos_type"] for f in fixes if f["valid"]} == {"SINGLE"}


def test_replay_keeps_the_recorded_pace_and_its_one_gap():
    twin = NovatelTwin(replay=load_drive(stop=200), replay_retime=True)
    h = TwinHarness(twin)
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05))
    h.run(10.0)
    steps = np.diff([m.gps_ms for m in h.logs])
    assert len(h.logs) == 91                           # 10 Hz, and 1 s missing after row 18
    assert list(steps).count(1000) == 1 and set(steps) == {100, 1000}
    # moved to the present: epochs are stamped on the twin's clock, not in 2016
    first = h.logs[0].gps_week * 604_800_000 + h.logs[0].gps_ms
    assert 0 < h.twin.clock.gps_ms(h.now) - first < 11_000


def test_a_slower_ontime_period_samples_the_recording():
    twin = NovatelTwin(replay=load_drive(stop=100), replay_retime=False)
    h = TwinHarness(twin)
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=1.0))
    h.run(10.0)
    assert [m.gps_ms % 1000 for m in h.logs] == [0] * len(h.logs) and 9 <= len(h.logs) <= 10


@pytest.mark.timeout(60)
def test_replay_over_socket_in_another_process(procs):
    start, stop = 3700, 3760                           # includes an INSUFFICIENT_OBS run
    url = start_twin(procs, "--replay", "drive", "--rows", str(start), str(stop),
                     "--replay-speed", "4", "--replay-keep-time")
    with NovatelReceiver(url) as rx:
        rx.startup(StartupConfig())
        got = [rx.read(timeout=5) for _ in range(stop - start)]
    for msg, row in zip(got, ROWS[start:stop]):
        assert_epoch_equals_row(msg, row)
    assert any(m.data.pos_status.name == "INSUFFICIENT_OBS" for m in got)
