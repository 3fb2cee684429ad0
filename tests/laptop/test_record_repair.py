"""A recorder killed with `kill -9` on the running simulated car (issue 15): what it leaves
loses at most the last second, and `viena record --repair` turns it into a file that
mcap's own seeking reader opens."""
from __future__ import annotations

import io
import os
import signal
import threading

import msgpack
import pytest
from laptop_helpers import TRUTH_KEY, VIENA, start_sim, viena, wait_for_samples
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from vienatest import wait_for_line, wait_for_subscriber, wait_until

from viena.record import FLUSH_PERIOD_S

pytestmark = pytest.mark.slow  # a router, the sim and the CLI as processes

TRUTH_RATE_HZ = 100
MAX_LOSS_S = 1.0


class _Pipe(io.RawIOBase):
    """A file that cannot seek, as a pipe or a socket: mcap then uses its streaming reader."""

    def __init__(self, data: bytes):
        self._data = io.BytesIO(data)

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        chunk = self._data.read(len(buffer))
        buffer[:len(chunk)] = chunk
        return len(chunk)


def truth_seqs(messages) -> list[tuple[int, int]]:
    """(seq, t ns) of the truth samples among mcap messages, in file order."""
    out = []
    for _schema, channel, message in messages:
        if channel.topic == TRUTH_KEY:
            sample = msgpack.unpackb(message.data)
            out.append((sample["seq"], sample["t"]))
    return out


@pytest.fixture
def killed_recording(tmp_path, procs, router, session):
    """`viena record` on the sim car for about 3 s, then SIGKILL: (the .part it left, the
    (seq, t) of every truth sample the car had published when it died, as a second
    subscriber saw them)."""
    start_sim(procs, router, tmp_path)
    wait_for_samples(session, TRUTH_KEY)
    seen: list[tuple[int, int]] = []
    lock = threading.Lock()

    def on_truth(sample) -> None:
        value = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            seen.append((value["seq"], value["t"]))
    sub = session.declare_subscriber(TRUTH_KEY, on_truth)
    out = tmp_path / "drive.mcap"
    rec = procs.start(*VIENA, "record", "--connect", router, "-o", out, "-q")
    wait_for_line(rec.stderr, "recording viena/**")
    assert wait_for_subscriber(session, TRUTH_KEY)
    with lock:
        start = len(seen)
    assert wait_until(lambda: len(seen) - start >= 3 * TRUTH_RATE_HZ, 20)
    os.kill(rec.pid, signal.SIGKILL)                     # no goodbye, no summary
    with lock:
        published = list(seen)
    sub.undeclare()
    rec.wait(timeout=10)
    assert not out.exists()
    return out.with_name("drive.mcap.part"), published


def test_a_killed_recording_is_repaired_into_a_file_mcap_opens(killed_recording, tmp_path):
    part, published = killed_recording
    repaired = tmp_path / "drive.mcap"

    result = viena("record", "--repair", part, timeout=60)
    assert result.returncode == 0, result.stderr
    assert f"repaired {part} into {repaired}" in result.stderr
    assert "the recorder did not finish" in result.stderr          # what was wrong, said
    assert part.exists()                                            # the evidence stays

    with open(repaired, "rb") as f:
        reader = make_reader(f)                                     # mcap's seeking reader
        assert reader.get_summary() is not None
        recorded = truth_seqs(reader.iter_messages(log_time_order=False))
    seqs = [seq for seq, _ in recorded]
    assert len(seqs) >= TRUTH_RATE_HZ
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a truth sample was lost"

    # what the car had published past the file's last truth sample: at most a second
    last_t = recorded[-1][1]
    lost = [t for seq, t in published if seq > seqs[-1]]
    lost_s = (max(lost) - last_t) / 1e9 if lost else 0.0
    print(f"kill -9: {len(lost)} truth samples lost, {lost_s:.2f} s (flush every {FLUSH_PERIOD_S} s)")
    assert lost_s <= MAX_LOSS_S
    assert len(lost) <= MAX_LOSS_S * TRUTH_RATE_HZ + 5


def test_a_killed_recording_without_repair(killed_recording):
    """What mcap's readers make of the `.part` itself: the seeking reader refuses it (no
    footer, no summary); the streaming reader reads every flushed chunk in file order, then
    ends with EndOfFile where the recorder died."""
    part, published = killed_recording
    with open(part, "rb") as f:
        with pytest.raises(McapError):                  # RecordLengthLimitExceeded: the missing footer
            list(make_reader(f).iter_messages())

    stream = make_reader(io.BufferedReader(_Pipe(part.read_bytes())))
    got: list = []
    with pytest.raises(EndOfFile):
        for message in stream.iter_messages(log_time_order=False):
            got.append(message)
    seqs = [seq for seq, _ in truth_seqs(got)]
    assert seqs and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    lost = [seq for seq, _ in published if seq > seqs[-1]]
    assert len(lost) <= MAX_LOSS_S * TRUTH_RATE_HZ + 5


def test_repair_refuses_what_is_not_a_recording(tmp_path):
    text = tmp_path / "notes.mcap.part"
    text.write_text("not an MCAP file\n")
    result = viena("record", "--repair", text, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip() == f"viena record: {text}: not an MCAP file"
    assert not (tmp_path / "notes.mcap").exists()
