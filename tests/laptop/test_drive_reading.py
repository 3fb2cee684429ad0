"""Reading a drive of the black box: its numbered files as one recording, the latched samples
each file repeats at its start read once, and each file still whole on its own
(`Drive` in common/recording.py; `viena record list`, `info`, `export` on a drive)."""
from __future__ import annotations

import csv
import json
from datetime import UTC, datetime
from pathlib import Path

import msgpack
import pytest
from laptop_helpers import viena

from viena.common import recording as rec
from viena.common.keys import Keys
from viena.common.recording import Drive, Recording, RecordingWriter, find_drives, open_source
from viena.common.samples import topics
from viena.record_list import Odometer, drive_row

KEYS = Keys("elettra")
PATH_KEY = KEYS.of(topics.PILOT_PATH)
STATE_KEY = KEYS.of(topics.ESTIMATOR_STATE)
PATH_ENCODING = "application/msgpack;viena.pilot.path/1"
STATE_ENCODING = "application/msgpack;viena.estimator.state/2"
T0 = int(datetime(2026, 5, 1, 10, 12, 3, tzinfo=UTC).timestamp()) * 1_000_000_000
STEP_NS = 100_000_000            # the estimator's state every 0.1 s in these drives
PER_FILE = 100                   # states a file: 10 s
SPEED_M_PER_STEP = 1.0           # eastwards, in a straight line


def path_sample() -> dict:
    return {"t": T0, "form": "points", "lat_deg": [45.0, 45.001], "lon_deg": [11.0, 11.0],
            "speeds_mps": [None, None], "length_m": 111.2}


def state_sample(i: int) -> dict:
    return {"t": T0 + i * STEP_NS, "seq": i, "position_valid": True, "origin": [45.0, 11.0, 30.0],
            "enu_m": [i * SPEED_M_PER_STEP, 0.0, 0.0]}


def write_drive(directory: Path, drive_id: str = "viena-20260501-101203", files: int = 3,
                start: int = T0, open_last: bool = False) -> list[tuple[str, int]]:
    """A drive as the recorder writes it: the pilot's path (latched) once at the start, then
    estimator states; each file after the first opens with the path again under its
    original log time. With `open_last` the last file is left `.part` (a power cut).
    Returns the drive's samples in order, each once, as (key, log time)."""
    directory.mkdir(parents=True, exist_ok=True)
    path = msgpack.packb(path_sample())
    written = [(PATH_KEY, start)]
    for n in range(1, files + 1):
        writer = RecordingWriter(directory / f"{drive_id}_{n:04d}.mcap",
                                 metadata={"drive": drive_id, "part": str(n), "car": "elettra"})
        writer.write(PATH_KEY, PATH_ENCODING, start, path, publish_time=T0)    # a repeat after file 1
        for i in range((n - 1) * PER_FILE, n * PER_FILE):
            log_time = start + (i + 1) * STEP_NS
            writer.write(STATE_KEY, STATE_ENCODING, log_time, msgpack.packb(state_sample(i)))
            written.append((STATE_KEY, log_time))
        if open_last and n == files:
            writer.flush()
            writer.abandon()
        else:
            writer.close()
    return written


@pytest.fixture
def drive(tmp_path):
    return tmp_path / "box", write_drive(tmp_path / "box")


def test_drive_file_names():
    assert rec.drive_file("viena-20260501-101203_0002.mcap") == ("viena-20260501-101203", 2)
    assert rec.drive_file("viena-20260501-101203-2_0010.mcap.part") == ("viena-20260501-101203-2", 10)
    assert rec.drive_file("drive.mcap") is None
    assert rec.drive_file("viena-20260501-101203_0001.mcap.broken") is None


def test_a_drive_reads_as_one_with_each_sample_once_in_order(drive):
    directory, written = drive
    found = find_drives(directory)
    assert list(found) == ["viena-20260501-101203"]
    assert [p.name for p in found["viena-20260501-101203"]] == [
        f"viena-20260501-101203_{n:04d}.mcap" for n in (1, 2, 3)]
    whole = Drive.in_directory(directory)
    assert whole.note is None
    read = [(m.key, m.log_time) for m in whole.messages()]
    assert read == written
    assert whole.repeats == 2 and whole.count == len(written)
    assert whole.complete and not whole.report() and not whole.cut_short
    assert (whole.first_log_time, whole.last_log_time) == (T0, T0 + 3 * PER_FILE * STEP_NS)
    assert whole.metadata["drive"] == "viena-20260501-101203" and "part" not in whole.metadata
    assert [(m.key, m.log_time) for m in whole.messages()] == written       # read again: the same


def test_the_key_filter_does_not_change_what_is_a_repeat(drive):
    directory, _ = drive
    only_path = [m.log_time for m in Drive.in_directory(directory).messages(rec.KeyFilter([PATH_KEY]))]
    assert only_path == [T0]


def test_each_file_alone_has_the_route(drive):
    directory, _ = drive
    for n, path in enumerate(find_drives(directory)["viena-20260501-101203"], 1):
        recording = Recording(path)
        messages = list(recording.messages())
        assert messages[0].key == PATH_KEY and messages[0].log_time == T0
        assert msgpack.unpackb(messages[0].data) == path_sample()
        assert len(messages) == 1 + PER_FILE
        assert recording.metadata["part"] == str(n) and recording.complete


def test_what_a_tool_is_given_decides_what_it_reads(drive, tmp_path):
    directory, written = drive
    one = directory / "viena-20260501-101203_0002.mcap"
    assert isinstance(open_source(one), Recording)
    assert isinstance(open_source(directory), Drive)
    by_id = open_source(directory / "viena-20260501-101203")
    assert isinstance(by_id, Drive) and len(by_id.files) == 3
    with pytest.raises(rec.RecordingError, match="one file"):
        open_source(one, "viena-20260501-101203")
    with pytest.raises(rec.RecordingError, match="no drive in it"):
        open_source(tmp_path)


def test_a_directory_of_several_drives_reads_the_newest_or_the_one_named(drive):
    directory, _ = drive
    later = T0 + 3600 * 1_000_000_000
    second = write_drive(directory, "viena-20260501-111203", files=2, start=later)
    said: list[str] = []
    newest = open_source(directory, say=said.append)
    assert isinstance(newest, Drive) and newest.id == "viena-20260501-111203"
    assert said and "newest, viena-20260501-111203" in said[0] and "--drive" in said[0]
    assert [(m.key, m.log_time) for m in newest.messages()] == second
    named = open_source(directory, "viena-20260501-101203")
    assert isinstance(named, Drive) and len(named.files) == 3
    with pytest.raises(rec.RecordingError, match="no drive viena-20990101-000000"):
        open_source(directory, "viena-20990101-000000")


def test_a_drive_cut_short_is_read_as_far_as_it_goes(tmp_path):
    directory = tmp_path / "box"
    written = write_drive(directory, open_last=True)
    files = find_drives(directory)["viena-20260501-101203"]
    assert files[-1].name.endswith("_0003.mcap.part")
    whole = Drive.in_directory(directory)
    read = [(m.key, m.log_time) for m in whole.messages()]
    assert read == written                          # flushed before the cut: every sample
    assert whole.cut_short and not whole.complete
    assert whole.stopped and "_0003.mcap.part" in whole.stopped

    rows = json.loads(viena("record", "list", directory, "--json").stdout)
    assert [(r["drive"], r["files"], r["cut_short"]) for r in rows] == [("viena-20260501-101203", 3, True)]
    table = viena("record", "list", directory)
    assert table.returncode == 0, table.stderr
    assert "cut short" in table.stdout


def test_record_list_rows(drive):
    directory, _ = drive
    write_drive(directory, "viena-20260501-111203", files=1, start=T0 + 3600 * 1_000_000_000)
    result = viena("record", "list", directory, "--json")
    assert result.returncode == 0, result.stderr
    rows = json.loads(result.stdout)
    assert [r["drive"] for r in rows] == ["viena-20260501-101203", "viena-20260501-111203"]
    first = rows[0]
    assert first["files"] == 3 and not first["cut_short"] and first["problems"] == []
    assert first["start_ns"] == T0 and first["duration_s"] == pytest.approx(3 * PER_FILE * 0.1)
    assert first["distance_from"] == "estimator"
    # 300 states 1 m apart, read every STEP_S = 0.2 s: 0 ... 298 m
    assert 290 <= first["distance_m"] <= 300
    assert first["bytes"] == sum(p.stat().st_size for p in directory.glob("viena-20260501-101203_*"))

    table = viena("record", "list", directory)
    lines = table.stdout.splitlines()
    assert lines[0].split()[:3] == ["DRIVE", "START", "(UTC)"]
    assert lines[1].startswith("viena-20260501-101203  2026-05-01 10:12:03  2026-05-01 10:12:33  0:00:30")
    assert "m estimator" in lines[1] and len(lines) == 3


def test_record_list_takes_the_fixes_when_there_is_no_estimator(tmp_path):
    directory = tmp_path / "box"
    directory.mkdir()
    writer = RecordingWriter(directory / "viena-20260501-101203_0001.mcap")
    fix_key = KEYS.of(topics.GNSS_FIX, unit="gnss0")
    for i in range(11):                          # 1e-4 deg of latitude a second: 11.1 m
        fix = {"t": T0 + i * 10**9, "valid": True, "lat_deg": 45.0 + i * 1e-4, "lon_deg": 11.0}
        writer.write(fix_key, "application/msgpack;viena.gnss.fix/1", T0 + i * 10**9, msgpack.packb(fix))
    writer.close()
    row = drive_row(Drive.in_directory(directory))
    assert row.distance_from == "gnss" and row.distance_m == pytest.approx(111.2, rel=0.01)


def test_an_odometer_ignores_a_standing_cars_noise():
    odometer = Odometer()
    for east in (0.0, 0.1, -0.1, 0.2, 0.0, 5.0, 5.1, 10.0):
        odometer.add(east, 0.0)
    assert odometer.m == pytest.approx(10.0)


def test_info_and_export_see_every_sample_of_a_drive_once(drive, tmp_path):
    directory, written = drive
    info = viena("info", directory, "--json")
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    assert summary["samples"] == len(written) and summary["drive"] == "viena-20260501-101203"
    assert summary["keys"][PATH_KEY]["count"] == 1
    assert summary["keys"][STATE_KEY]["count"] == 3 * PER_FILE
    assert len(summary["files"]) == 3 and summary["complete"]
    text = viena("info", directory)
    assert "3 files, 2 latched repeats read once" in text.stdout

    result = viena("export", directory, "--csv", tmp_path / "csv")
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "csv" / (PATH_KEY.replace("/", ".") + ".csv"), newline="") as f:
        assert len(list(csv.DictReader(f))) == 1
    with open(tmp_path / "csv" / (STATE_KEY.replace("/", ".") + ".csv"), newline="") as f:
        times = [int(row["log_time_ns"]) for row in csv.DictReader(f)]
    assert times == [t for key, t in written if key == STATE_KEY]

    one = viena("export", directory / "viena-20260501-101203_0002.mcap", "--json")
    keys = [json.loads(line)["key"] for line in one.stdout.splitlines()]
    assert keys == [PATH_KEY] + [STATE_KEY] * PER_FILE              # a file alone: the route too


def test_replay_plays_a_drive_once_through(drive):
    """What `viena replay DIR` publishes: every sample once, in order, across the files."""
    from viena.replay import Player, build_parser

    directory, written = drive
    put: list[tuple[str, int]] = []

    class Publisher:
        def __init__(self, key):
            self.key = key

        def put(self, data):
            put.append((self.key, msgpack.unpackb(data)["t"]))

    class Session:
        def declare_publisher(self, key, **_):
            return Publisher(key)

    class NeverStop:
        def is_set(self):
            return False

    args = build_parser().parse_args([str(directory), "--drive", "viena-20260501-101203", "--rate", "0"])
    source = open_source(args.file, args.drive)
    Player(Session(), rate=0).play(source.messages(), NeverStop())
    assert [key for key, _ in put] == [key for key, _ in written]
    assert [t for key, t in put if key == STATE_KEY] == [T0 + i * STEP_NS for i in range(3 * PER_FILE)]


def test_drives_started_in_the_same_second_list_in_order(tmp_path):
    for drive_id in ("viena-20260501-101203-10", "viena-20260501-101203", "viena-20260501-101203-2"):
        (tmp_path / f"{drive_id}_0001.mcap").write_bytes(b"")
    assert list(find_drives(tmp_path)) == [
        "viena-20260501-101203", "viena-20260501-101203-2", "viena-20260501-101203-10"]
