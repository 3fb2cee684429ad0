"""The black box's files (issue 30): a drive written as numbered split files into a
directory, split by size and by log time, the latched topics repeated at the start of every
file, a budget that drops the oldest closed files, and the leftovers of a killed run
repaired before the next one starts. The writer is driven with log times the test chooses:
no clock, no sleeps."""
from __future__ import annotations

import errno
import os
import re
from datetime import UTC, datetime
from pathlib import Path

import msgpack
import pytest
from laptop_helpers import TRUTH_ENCODING, TRUTH_KEY, VIENA, start_sim, wait_for_samples
from mcap.reader import make_reader
from vienatest import wait_for_line

from viena.common.drive_files import DriveWriter, drive_files, drive_name, trim_to_budget
from viena.common.recorder import Recorder
from viena.common.recording import Recording, RecordingWriter, drive_file

T0 = 1_717_236_000_000_000_000                    # 2024-06-01 10:00:00 UTC
DRIVE = "viena-20240601-100000"
PATH_KEY = "viena/elettra/pilot/path"
PATH_ENCODING = "application/msgpack;viena.pilot.path/1"
MS = 1_000_000


def truth(seq: int, t: int) -> bytes:
    """A truth-sized sample (about 200 bytes) that compresses like one: numbers that move."""
    return msgpack.packb({"t": t, "seq": seq, "x": [seq * 0.37 + i * 1.1 for i in range(20)]})


def path_sample(t: int) -> bytes:
    return msgpack.packb({"t": t, "points": [[0.0, 0.0], [10.0, 5.0]]})


def write_drive(writer: DriveWriter, seconds: float, start: int = T0, rate_hz: int = 100) -> int:
    """`seconds` of truth at `rate_hz` from `start`, log time 2 ms after each sample's t; the
    last log time."""
    step = 1_000_000_000 // rate_hz
    t = start
    for seq in range(int(seconds * rate_hz)):
        t = start + seq * step
        writer.write(TRUTH_KEY, TRUTH_ENCODING, t + 2 * MS, truth(seq, t))
    return t + 2 * MS


def closed(directory: Path) -> list[Path]:
    return sorted(directory.glob("*.mcap"))


def messages(path: Path) -> list:
    """Every message as mcap's own seeking reader sees it: (topic, log time, publish time)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        return [(c.topic, m.log_time, m.publish_time)
                for _s, c, m in reader.iter_messages(log_time_order=False)]


def test_a_drive_splits_by_log_time_into_numbered_files(tmp_path):
    writer = DriveWriter(tmp_path, split_s=1.0, started_ns=T0, metadata={"car": "elettra"})
    write_drive(writer, 3.5)
    last = writer.close()

    files = closed(tmp_path)
    assert [f.name for f in files] == [f"{DRIVE}_{n:04d}.mcap" for n in (1, 2, 3, 4)]
    assert last == files[-1] and not list(tmp_path.glob("*.part"))
    total = 0
    for n, path in enumerate(files, 1):
        recording = Recording(path)
        got = list(recording.messages())
        assert recording.complete and not recording.report()
        assert recording.metadata["drive"] == DRIVE and recording.metadata["part"] == str(n)
        assert recording.metadata["car"] == "elettra"
        assert len(messages(path)) == len(got)
        span = got[-1].log_time - got[0].log_time
        assert span < 1_000_000_000                       # each covers less than split_s
        total += len(got)
    assert total == writer.samples == 350


def test_a_drive_splits_by_size(tmp_path):
    writer = DriveWriter(tmp_path, split_bytes=8_000, chunk_size=2_000, started_ns=T0)
    write_drive(writer, 5.0)
    writer.close()

    files = closed(tmp_path)
    assert len(files) >= 3
    assert [drive_file(f)[1] for f in files] == list(range(1, len(files) + 1))
    sizes = [f.stat().st_size for f in files]
    assert all(size < 8_000 + 2 * 2_000 + 4_000 for size in sizes)   # the limit, a chunk, the summary
    assert sum(len(messages(f)) for f in files) == 500
    assert writer.size == sum(sizes)


def test_a_latched_topic_opens_every_later_file_at_its_start(tmp_path):
    """The route opens each later file, logged at the file's start (so the file read alone
    replays from its own start) with its own publish time; the file says how many such
    repeats it begins with, and a reader of the drive skips exactly those."""
    writer = DriveWriter(tmp_path, split_s=1.0, started_ns=T0)
    path_t = T0 + 5 * MS
    writer.write(PATH_KEY, PATH_ENCODING, path_t + 2 * MS, path_sample(path_t))
    write_drive(writer, 2.5, start=T0 + 10 * MS)
    writer.close()

    files = closed(tmp_path)
    assert len(files) == 3
    for later in files[1:]:
        got = messages(later)
        assert got[0][0] == PATH_KEY and got[0][2] == path_t             # its own publish time ...
        assert got[1][0] == TRUTH_KEY and got[1][1] == got[0][1]         # ... logged at the file's start
        reading = Recording(later)
        list(reading.messages())
        assert reading.metadata["repeats"] == "1"
        assert [m for m in got if m[0] == PATH_KEY] == [got[0]]          # once per file
        channel = {c.topic: c for c in make_reader(open(later, "rb")).get_summary().channels.values()}
        assert channel[PATH_KEY].metadata["viena_latched"] == "true"
        assert channel[TRUTH_KEY].metadata["viena_latched"] == "false"
    assert writer.samples == 1 + 250                      # the repeats are not new samples


def test_the_drive_name_is_new_in_its_directory(tmp_path):
    assert drive_name(tmp_path, T0) == DRIVE
    (tmp_path / f"{DRIVE}_0001.mcap").write_bytes(b"")
    assert drive_name(tmp_path, T0) == f"{DRIVE}-2"
    (tmp_path / f"{DRIVE}-2_0003.mcap.broken").write_bytes(b"")
    assert drive_name(tmp_path, T0) == f"{DRIVE}-3"


def test_the_budget_drops_the_oldest_closed_files_never_the_open_one(tmp_path):
    said: list[str] = []
    keep = 30_000
    writer = DriveWriter(tmp_path, split_bytes=8_000, chunk_size=2_000, keep_bytes=keep,
                         started_ns=T0, say=said.append)
    largest = 0
    for second in range(20):
        write_drive(writer, 1.0, start=T0 + second * 1_000_000_000)
        assert writer.part.exists()                                       # the open file stays
        on_disk = [f.stat().st_size for f in closed(tmp_path)]
        largest = max([largest, *on_disk])
        assert sum(on_disk) <= keep
        assert sum(on_disk) + writer.part.stat().st_size <= keep + largest + 2_000
    writer.close()
    files = closed(tmp_path)
    assert sum(f.stat().st_size for f in files) <= keep
    assert files[-1] == writer.closed[-1]                                # the newest are kept
    numbers = [drive_file(f)[1] for f in files]
    assert numbers == list(range(numbers[0], numbers[-1] + 1)) and numbers[0] > 1
    deletions = [line for line in said if line.startswith("deleted the")]
    assert deletions and f"{DRIVE}_0001.mcap" in deletions[0]
    assert re.fullmatch(r"deleted the \d+ oldest files \(.+\) to keep .+ within 30\.0 kB: .+", deletions[0])


def test_the_budget_takes_drives_oldest_first_and_leaves_other_files(tmp_path):
    for name in ("viena-20240601-100000-2_0001.mcap", "viena-20240601-100000_0002.mcap",
                 "viena-20240601-100000_0001.mcap", "viena-20240531-235959_0007.mcap", "mine.mcap"):
        (tmp_path / name).write_bytes(b"x" * 100)
    assert [p.name for p in drive_files(tmp_path)] == [
        "viena-20240531-235959_0007.mcap", "viena-20240601-100000_0001.mcap",
        "viena-20240601-100000_0002.mcap", "viena-20240601-100000-2_0001.mcap"]
    gone = trim_to_budget(tmp_path, 250, say=lambda line: None)
    assert [p.name for p in gone] == ["viena-20240531-235959_0007.mcap", "viena-20240601-100000_0001.mcap"]
    assert (tmp_path / "mine.mcap").exists()


def killed_writer(path: Path, samples: int) -> None:
    """What a recorder killed with kill -9 leaves: a `.part` flushed up to `samples`."""
    writer = RecordingWriter(path, metadata={"drive": "viena-20240601-095000", "part": "1"})
    for seq in range(samples):
        writer.write(TRUTH_KEY, TRUTH_ENCODING, T0 + seq * 10 * MS, truth(seq, T0 + seq * 10 * MS))
    writer.flush()
    writer.write(TRUTH_KEY, TRUTH_ENCODING, T0 + 10**9, truth(999, T0 + 10**9))     # in no chunk
    writer._file.flush()                                  # the bytes the kernel had, no summary


def test_the_leftovers_of_a_killed_run_are_repaired_before_the_first_file(tmp_path):
    killed_writer(tmp_path / "viena-20240601-095000_0001.mcap", 120)
    (tmp_path / "viena-20240601-095500_0001.mcap.part").write_bytes(b"not an MCAP file")
    said: list[str] = []

    writer = DriveWriter(tmp_path, split_s=1.0, started_ns=T0, say=said.append)
    repaired = tmp_path / "viena-20240601-095000_0001.mcap"
    assert not (tmp_path / "viena-20240601-095000_0001.mcap.part").exists()
    recording = Recording(repaired)
    assert len(list(recording.messages())) == 120 and recording.complete
    assert recording.metadata["drive"] == "viena-20240601-095000"
    assert len(messages(repaired)) == 120
    assert (tmp_path / "viena-20240601-095500_0001.mcap.broken").exists()
    assert not (tmp_path / "viena-20240601-095500_0001.mcap.part").exists()
    assert len(said) == 2
    assert said[0].startswith("repaired viena-20240601-095000_0001.mcap.part, left by the last run, "
                              "into viena-20240601-095000_0001.mcap: 120 samples")
    assert "cannot be read" in said[1] and "kept as viena-20240601-095500_0001.mcap.broken" in said[1]
    writer.discard()


def test_a_drive_killed_mid_file_is_repaired_by_the_next_run(tmp_path):
    first = DriveWriter(tmp_path, split_s=1.0, started_ns=T0)
    write_drive(first, 1.5)
    first.flush()
    first._writer._file.flush()                            # then kill -9: no close, no summary
    first._lock_file.close()                               # ... and the kernel lets go of its lock
    assert [p.name for p in tmp_path.glob("*.part")] == [f"{DRIVE}_0002.mcap.part"]

    second = DriveWriter(tmp_path, split_s=1.0, started_ns=T0)
    assert second.drive == f"{DRIVE}-2"
    files = closed(tmp_path)
    assert [f.name for f in files] == [f"{DRIVE}_0001.mcap", f"{DRIVE}_0002.mcap"]
    assert sum(len(messages(f)) for f in files) == 150
    second.discard()


def test_a_second_writer_into_the_same_directory_is_refused(tmp_path):
    """It would repair the first one's open file from under it."""
    first = DriveWriter(tmp_path, split_s=1.0, started_ns=T0)
    write_drive(first, 0.5)
    with pytest.raises(OSError, match="another recorder writes into"):
        DriveWriter(tmp_path, split_s=1.0, started_ns=T0)
    assert [p.name for p in tmp_path.glob("*.part")] == [f"{DRIVE}_0001.mcap.part"]
    first.close()
    DriveWriter(tmp_path, split_s=1.0, started_ns=T0).discard()      # free again once it closed


def test_a_repair_that_lost_more_than_the_tail_keeps_the_original(tmp_path):
    part = tmp_path / f"{DRIVE}_0001.mcap.part"
    writer = RecordingWriter(tmp_path / f"{DRIVE}_0001.mcap", chunk_size=2_000)
    for i in range(300):
        writer.write(TRUTH_KEY, TRUTH_ENCODING, T0 + i * MS, msgpack.packb({"t": T0 + i * MS, "pad": os.urandom(64)}))
    writer.flush()
    writer._file.flush()
    data = bytearray(part.read_bytes())
    data[len(data) // 2:len(data) // 2 + 64] = b"\0" * 64             # a damaged chunk in the middle
    part.write_bytes(bytes(data))
    said: list[str] = []
    DriveWriter(tmp_path, split_s=1.0, started_ns=T0 + 10**12, say=said.append).discard()
    assert (tmp_path / f"{DRIVE}_0001.mcap").exists() and (tmp_path / f"{DRIVE}_0001.mcap.broken").exists()
    assert not part.exists() and any("original kept" in line for line in said)


class FakeSession:
    """A session that hands the test its subscribers' callbacks."""

    def __init__(self):
        self.callbacks: list = []

    def declare_subscriber(self, keyexpr, callback):
        self.callbacks.append(callback)
        return self

    def undeclare(self) -> None:
        pass


class FullDisk(RecordingWriter):
    def write(self, *args, **kw) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")


class Sample:
    key_expr, encoding = TRUTH_KEY, TRUTH_ENCODING

    class payload:                                       # noqa: N801 - zenoh's ZBytes, as read
        @staticmethod
        def to_bytes() -> bytes:
            return truth(0, T0)


def test_a_write_error_is_said_once_to_whoever_asked(tmp_path):
    errors: list[OSError] = []
    session = FakeSession()
    recorder = Recorder(session, ["viena/**"], FullDisk(tmp_path / "x.mcap"), on_error=errors.append)
    recorder.start()
    for _ in range(3):
        session.callbacks[0](Sample)
    assert recorder.failed.wait(10)
    assert recorder.stop() is None
    assert len(errors) == 1 and errors[0].errno == errno.ENOSPC and recorder.error is errors[0]
    assert (tmp_path / "x.mcap.part").exists()


@pytest.mark.slow  # a router, the sim and the CLI as processes
def test_viena_record_writes_a_drive_from_the_sim_car(tmp_path, procs, router, session):
    start_sim(procs, router, tmp_path)
    wait_for_samples(session, TRUTH_KEY)
    out = tmp_path / "drive"
    rec = procs.start(*VIENA, "record", "--connect", router, "-o", out, "--split-s", "1",
                      "--keep-gb", "1", "--duration", "3.5", "-q")
    wait_for_line(rec.stderr, "recording viena/**")
    assert rec.wait(timeout=60) == 0
    last = rec.stderr.read()
    files = closed(out)
    assert len(files) >= 3 and not list(out.glob("*.part"))
    drive = datetime.now(UTC).strftime("viena-%Y%m%d")
    assert all(f.name.startswith(drive) for f in files)
    assert f"into {out}: {len(files)} files of drive" in last
    for path in files:
        recording = Recording(path)
        keys = {m.key for m in recording.messages()}
        assert TRUTH_KEY in keys and recording.complete
        assert messages(path)


def test_the_budget_counts_the_kept_originals_too(tmp_path):
    """A `.broken` original is as old as its drive: it goes in its turn, and counts meanwhile."""
    sizes = {"viena-20240601-100000_0001.mcap.broken": 4000, "viena-20240601-100000_0001.mcap": 3000,
             "viena-20240601-100000_0002.mcap": 3000, "viena-20240601-110000_0001.mcap.broken": 4000,
             "viena-20240601-110000_0001.mcap": 3000, "mine.mcap.broken": 9000}
    for name, size in sizes.items():
        (tmp_path / name).write_bytes(b"x" * size)
    gone = trim_to_budget(tmp_path, 7_000, lambda line: None)
    assert [p.name for p in gone] == ["viena-20240601-100000_0001.mcap", "viena-20240601-100000_0001.mcap.broken",
                                      "viena-20240601-100000_0002.mcap"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.mcap.broken", "viena-20240601-110000_0001.mcap",
                                                          "viena-20240601-110000_0001.mcap.broken"]


def test_a_repair_cut_short_is_done_again_and_its_leftover_deleted(tmp_path):
    """A crash while repairing left a `.repairing` beside the `.part`: the next run deletes it
    (it would sit outside the budget for ever) and repairs the `.part` again."""
    killed_writer(tmp_path / "viena-20240601-095000_0001.mcap", 120)
    stale = tmp_path / "viena-20240601-095000_0001.mcap.repairing"
    stale.write_bytes(b"half a repair")
    orphan = tmp_path / "viena-20240601-094000_0001.mcap.repairing"      # its .part went to .broken
    orphan.write_bytes(b"half a repair")
    said: list[str] = []
    DriveWriter(tmp_path, split_s=1.0, started_ns=T0, say=said.append).discard()
    assert not stale.exists() and not orphan.exists()
    assert len(messages(tmp_path / "viena-20240601-095000_0001.mcap")) == 120
    assert sum("a repair cut short" in line for line in said) == 2
