"""Bad files and bad places: truncated and corrupted recordings are read as far as they go,
and a recorder that cannot write says so and claims no file as good."""
from __future__ import annotations

import os
import queue
import resource
import signal
import struct

import msgpack
import pytest
from laptop_helpers import VIENA, viena
from vienatest import open_session, wait_for_line, wait_for_subscriber, wait_until

from viena.common.recording import Recording, RecordingError, RecordingWriter

KEY = "viena/elettra/test/sample"
ENCODING = "application/msgpack;viena.test/1"
T0 = 1_717_236_000_000_000_000


def sample(i: int) -> bytes:
    # incompressible padding, so that a few hundred samples make several chunks
    return msgpack.packb({"t": T0 + i * 10_000_000, "seq": i, "pad": os.urandom(200)})


def write_samples(path, n: int, close: bool = True) -> tuple[RecordingWriter, list[bytes]]:
    writer = RecordingWriter(path, chunk_size=8 * 1024)
    data = [sample(i) for i in range(n)]
    for i, d in enumerate(data):
        writer.write(KEY, ENCODING, T0 + i * 10_000_000 + 1000, d)
    if close:
        writer.close()
    return writer, data


def chunk_offsets(path) -> list[int]:
    """Byte offsets of the top-level chunk records (opcode 0x06)."""
    raw = path.read_bytes()
    offsets, pos = [], 8
    while pos < len(raw) - 8:
        opcode, length = raw[pos], struct.unpack_from("<Q", raw, pos + 1)[0]
        if opcode == 0x06:
            offsets.append(pos)
        if opcode == 0x02:                      # footer: the end
            break
        pos += 9 + length
    return offsets


def test_a_good_recording_reads_back_exactly(tmp_path):
    path = tmp_path / "good.mcap"
    _, data = write_samples(path, 300)
    recording = Recording(path)
    got = list(recording.messages())
    assert [m.data for m in got] == data
    assert [m.publish_time for m in got] == [T0 + i * 10_000_000 for i in range(300)]
    assert {(m.key, m.encoding, m.schema) for m in got} == {(KEY, ENCODING, "viena.test/1")}
    assert recording.complete and recording.report() == []


@pytest.mark.parametrize("fraction", [0.3, 0.77])
def test_a_truncated_recording_reads_up_to_the_cut(tmp_path, fraction):
    path = tmp_path / "cut.mcap"
    _, data = write_samples(path, 400)
    raw = path.read_bytes()
    path.write_bytes(raw[:int(len(raw) * fraction)])
    recording = Recording(path)
    got = [m.data for m in recording.messages()]
    assert 0 < len(got) < len(data)
    assert got == data[:len(got)]                     # a clean prefix, nothing invented
    assert not recording.complete
    assert recording.stopped.startswith("stopped at byte ")
    assert f"after {len(got)} samples" in recording.stopped
    assert "s into the recording" in recording.stopped


def test_a_damaged_chunk_is_skipped_and_reading_goes_on(tmp_path):
    path = tmp_path / "bad.mcap"
    _, data = write_samples(path, 400)
    chunks = chunk_offsets(path)
    assert len(chunks) >= 4
    raw = bytearray(path.read_bytes())
    victim = chunks[1] + 9 + 60                        # inside the second chunk's compressed data
    raw[victim:victim + 16] = bytes(16)
    path.write_bytes(bytes(raw))
    recording = Recording(path)
    got = [m.data for m in recording.messages()]
    assert recording.complete and recording.stopped is None
    assert len(recording.problems) == 1 and "damaged chunk skipped" in recording.problems[0]
    assert f"byte {chunks[1]}" in recording.problems[0]
    lost = [d for d in data if d not in got]
    assert 0 < len(lost) < len(data) // 2
    assert got == [d for d in data if d in got]        # the rest, in order
    assert got[-1] == data[-1]                          # reading went on to the end


def test_a_broken_record_length_stops_reading_there(tmp_path):
    path = tmp_path / "framing.mcap"
    _, data = write_samples(path, 400)
    chunks = chunk_offsets(path)
    raw = bytearray(path.read_bytes())
    struct.pack_into("<Q", raw, chunks[2] + 1, 1 << 40)        # the third chunk's length
    path.write_bytes(bytes(raw))
    recording = Recording(path)
    got = [m.data for m in recording.messages()]
    assert got == data[:len(got)] and 0 < len(got) < len(data)
    assert recording.stopped.startswith(f"stopped at byte {chunks[2]} of ")
    assert "unreadable record" in recording.stopped


def test_an_unfinished_recording_reads_its_whole_chunks(tmp_path):
    """A recorder killed mid-drive leaves a .part without summary or footer."""
    path = tmp_path / "killed.mcap"
    writer, data = write_samples(path, 300, close=False)
    writer._file.flush()                               # what the OS had when it was killed
    writer.abandon()
    assert not path.exists()
    recording = Recording(writer.part)
    got = [m.data for m in recording.messages()]
    assert 0 < len(got) < len(data) and got == data[:len(got)]
    assert "the recorder did not finish" in recording.stopped


def test_not_a_recording(tmp_path):
    empty, text = tmp_path / "empty.mcap", tmp_path / "text.mcap"
    empty.write_bytes(b"")
    text.write_text("hello, this is not an MCAP file at all\n")
    for path in (empty, text, tmp_path / "missing.mcap"):
        with pytest.raises(RecordingError, match=str(path.name)):
            Recording(path)
    result = viena("replay", text, "--connect", "tcp/127.0.0.1:9")
    assert result.returncode == 2
    assert result.stderr.strip() == f"viena replay: {text}: not an MCAP file"


def test_replay_of_a_truncated_recording_plays_the_readable_part(tmp_path, router, session):
    path = tmp_path / "cut.mcap"
    _, data = write_samples(path, 400)
    raw = path.read_bytes()
    path.write_bytes(raw[:len(raw) // 2])
    readable = [m.data for m in Recording(path).messages()]
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(KEY, lambda s: got.put(s.payload.to_bytes()))
    with open_session(router) as probe:
        assert wait_for_subscriber(probe, KEY)
    result = viena("replay", path, "--connect", router, "--rate", 0)
    wait_until(lambda: got.qsize() >= len(readable), 5)
    sub.undeclare()
    assert result.returncode == 1
    assert f"viena replay: {path}: stopped at byte " in result.stderr
    assert f"replayed {len(readable)} samples" in result.stderr
    assert [got.get_nowait() for _ in range(got.qsize())] == readable


@pytest.mark.parametrize("where", ["missing-dir/drive.mcap", "a-directory", "/proc/drive.mcap"])
def test_record_into_an_unwritable_place_is_one_clear_line(tmp_path, where):
    (tmp_path / "a-directory").mkdir()
    target = tmp_path / where
    result = viena("record", "--connect", "tcp/127.0.0.1:9", "-o", target, timeout=30)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"viena record: cannot write {target}: ")
    assert not target.with_name(target.name + ".part").exists() or where == "a-directory"
    assert not (tmp_path / "a-directory.part").exists()


def _small_disk():
    """The recorder's "disk" holds 400 kB: writing past it fails as a full disk does."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000))


def test_record_into_a_full_disk_says_so_and_claims_no_good_file(tmp_path, procs, router, session):
    out = tmp_path / "drive.mcap"
    rec = procs.start(*VIENA, "record", "--connect", router, "-o", out, "-q", KEY,
                      preexec_fn=_small_disk)
    wait_for_line(rec.stderr, "recording")
    assert wait_for_subscriber(session, KEY)
    import zenoh
    pub = session.declare_publisher(KEY, encoding=zenoh.Encoding(ENCODING),
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    for i in range(3000):                              # ~700 kB of incompressible samples
        pub.put(sample(i))
        if rec.poll() is not None:
            break
    pub.undeclare()
    _, err = rec.communicate(timeout=20)
    assert rec.returncode == 1
    assert err.strip().startswith(f"viena record: cannot write {out}: File too large (after ")
    assert "not a complete recording" in err and "Traceback" not in err
    assert not out.exists()
    part = out.with_name("drive.mcap.part")
    assert part.exists()
    readable = Recording(part)
    assert len(list(readable.messages())) > 0 and readable.stopped
