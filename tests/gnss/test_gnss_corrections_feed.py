"""What of the corrections goes to the receiver (common/rtcm3.py, driver/novatel/feed.py, writer.py):
whole RTCM 3 frames, only the types an OEM4 decodes, never more than the line carries."""
from __future__ import annotations

import sys
import threading

import pytest
import serial
from pyrtcm import RTCMReader
from pyrtcm.rtcmhelpers import calc_crc24q
from vienatest import wait_until

from viena.common.rtcm3 import Rtcm3Framer as Rtcm3Splitter
from viena.common.rtcm3 import family
from viena.common.rtcm3 import message_number as message_type
from viena.services.gnss.driver.novatel.corrections import RTCM3_DECODED
from viena.services.gnss.driver.novatel.feed import CorrectionsFeed, LineBudget, line_bytes_per_s
from viena.services.gnss.driver.novatel.writer import CorrectionsWriter


def rtcm3(number: int, size: int = 20, fill: int = 0x55) -> bytes:
    """A frame of message `number` with a `size`-byte message (its number, then filler)."""
    body = bytes([number >> 4, (number & 0xF) << 4]) + bytes([fill]) * (size - 2)
    head = bytes([0xD3, (size >> 8) & 0x03, size & 0xFF])
    return head + body + calc_crc24q(head + body).to_bytes(3, "big")


def test_a_real_1005_frame_from_pyrtcm_is_one_frame_of_its_type():
    rtcm = pytest.importorskip("viena.services.ntrip.simulator.rtcm")
    frame = rtcm.arp(1005, 2050, (4918528.0, -791210.0, 3969759.0))
    assert RTCMReader.parse(frame).identity == "1005"
    got = Rtcm3Splitter().feed(frame)
    assert [(f.type, f.data) for f in got] == [(1005, frame)]


def test_frames_cut_anywhere_come_out_whole_and_garbage_between_is_skipped():
    stream = rtcm3(1004, 100) + b"\x00junk\xd3\xff" + rtcm3(1005, 19) + rtcm3(1074, 300)
    splitter = Rtcm3Splitter()
    out = []
    for i in range(0, len(stream), 7):
        out += splitter.feed(stream[i:i + 7])
    assert [f.type for f in out] == [1004, 1005, 1074]
    assert b"".join(f.data for f in out) == rtcm3(1004, 100) + rtcm3(1005, 19) + rtcm3(1074, 300)
    assert splitter.garbage_bytes == 7 and splitter.pending == 0


def test_a_frame_with_a_bad_crc_is_skipped_and_the_next_one_found():
    bad = bytearray(rtcm3(1004, 40))
    bad[10] ^= 0x01
    splitter = Rtcm3Splitter()
    got = splitter.feed(bytes(bad) + rtcm3(1006, 21))
    assert [f.type for f in got] == [1006]
    assert splitter.crc_errors >= 1 and splitter.garbage_bytes == len(bad)


def test_families_name_what_is_dropped():
    assert [family(t) for t in (1074, 1084, 1127, 1230, 1033, 1019, 1012, 4094)] == [
        "MSM", "MSM", "MSM", "GLONASS biases", "antenna descriptors", "ephemerides", "GLONASS observables",
        "proprietary"]
    assert message_type(rtcm3(1077)) == 1077


def test_types_the_receiver_cannot_decode_are_dropped_before_the_line_and_counted():
    feed = CorrectionsFeed("RTCMV3", RTCM3_DECODED, line_bytes_per_s(115200))
    data = rtcm3(1005) + rtcm3(1074, 200) + rtcm3(1004, 150) + rtcm3(1084, 180) + rtcm3(1230, 10)
    taken = feed.take(data, "RTCMV3", 0.0)
    assert taken.data == rtcm3(1005) + rtcm3(1004, 150) and taken.frames == 2
    assert taken.new_dropped_types == [1074, 1084, 1230]
    assert dict(feed.counts.dropped_types) == {1074: 1, 1084: 1, 1230: 1}
    assert feed.counts.dropped["type"] == 206 + 186 + 16
    again = feed.take(rtcm3(1074, 200) + rtcm3(1004), "RTCMV3", 0.1)
    assert again.new_dropped_types == [] and feed.counts.dropped_types[1074] == 2   # said once per type


def test_the_line_budget_is_the_baud_rate_less_a_margin():
    assert line_bytes_per_s(9600) == pytest.approx(864.0)
    budget = LineBudget(2000.0, burst_s=1.0)
    assert budget.take(2000, 0.0) and not budget.take(1, 0.0)
    assert not budget.take(600, 0.25) and budget.take(500, 0.25)   # a quarter second refills 500
    assert LineBudget(27.0).capacity == 1029                          # 300 baud: still one whole frame


def test_a_flood_drops_whole_frames_and_the_line_never_carries_more_than_its_rate():
    """30 kB/s of 1004 frames at 9600 baud (864 B/s usable): over 10 s, no more than a
    second's bucket plus 10 s at the line's rate goes out, every byte of it whole frames."""
    feed = CorrectionsFeed("RTCMV3", RTCM3_DECODED, line_bytes_per_s(9600))
    frame = rtcm3(1004, 300)
    written = b""
    flooded = 0
    for step in range(1000):                        # 100 frames a second for 10 s
        taken = feed.take(frame, "RTCMV3", step * 0.01)
        flooded += taken.flooded
        written += taken.data
        feed.wrote(taken)
    assert len(written) <= 864 * 1.0 + 864 * 10.0 and len(written) % len(frame) == 0
    assert len(written) >= 864 * 10.0 - len(frame)                 # and the line is used
    assert feed.counts.dropped["flood"] == 1000 * len(frame) - len(written) and flooded > 900
    assert feed.counts.bytes_written == len(written)


def test_other_formats_go_as_they_come_but_rtcm3_frames_to_them_are_the_wrong_format():
    feed = CorrectionsFeed("RTCM", None, line_bytes_per_s(115200))
    raw = bytes(range(64, 128))                      # RTCM 2.x is 6-of-8 bytes: passed as is
    assert feed.take(raw, "RAW", 0.0).data == raw
    wrong = feed.take(rtcm3(1004), "RTCMV3", 0.0)
    assert wrong.wrong_format and wrong.data == b"" and feed.counts.dropped["format"] == len(rtcm3(1004))


def test_the_writer_drops_while_not_ready_and_counts_a_failing_port():
    feed = CorrectionsFeed("RTCMV3", RTCM3_DECODED, line_bytes_per_s(115200))
    sent, errors = [], []
    writer = CorrectionsWriter(feed, on_port_error=errors.append)
    writer.write_now(rtcm3(1004), "RTCMV3")
    assert feed.counts.dropped["not_ready"] == len(rtcm3(1004)) and not sent
    writer.attach(sent.append)
    writer.write_now(rtcm3(1004) + rtcm3(1077), "RTCMV3")
    assert sent == [rtcm3(1004)] and feed.counts.bytes_written == len(rtcm3(1004))

    def broken(data):
        raise serial.SerialException("gone")
    writer.attach(broken)
    writer.write_now(rtcm3(1005), "RTCMV3")
    assert feed.counts.dropped["port"] == len(rtcm3(1005)) and str(errors[0]) == "gone"


def test_the_writer_thread_writes_what_is_put_and_a_full_queue_drops():
    feed = CorrectionsFeed("RTCMV3", RTCM3_DECODED, line_bytes_per_s(115200))
    sent = []
    writer = CorrectionsWriter(feed, queue_size=2)
    writer.attach(sent.append)
    for _ in range(5):                              # not started: the queue holds two
        writer.put(rtcm3(1004), "RTCMV3")
    assert writer.queue_dropped_bytes == 3 * len(rtcm3(1004))
    writer.start()
    try:
        assert wait_until(lambda: len(sent) >= 2, timeout=5.0)
    finally:
        writer.stop()
    assert sent == [rtcm3(1004)] * 2


def conserved(feed: CorrectionsFeed) -> bool:
    """Every byte in is written, dropped for a reason, or waiting in the framer."""
    c = feed.counts
    return c.bytes_in == c.bytes_written + sum(c.dropped.values()) + feed.splitter.pending


def test_attach_from_another_thread_while_writing_never_breaks_the_step():
    """The supervisor's attach() (detach, reconnect) while the writer's thread is inside the
    framer: the framer is reset on the writer's own thread, and every byte is accounted."""
    feed = CorrectionsFeed("RTCMV3", None, 1e9)
    writer = CorrectionsWriter(feed)
    sinks = [bytearray(), bytearray()]
    writer.attach(sinks[0].extend)
    stop, errors = threading.Event(), []

    def flip():
        i = 0
        while not stop.is_set():
            writer.attach(sinks[i % 2].extend if i % 3 else None)
            i += 1
    data = (b"\xd3\x00" + rtcm3(1005, 19)[:7]) * 3 + (rtcm3(1005, 19) + rtcm3(1004, 100)) * 10
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    flipper = threading.Thread(target=flip)
    flipper.start()
    try:
        for n in range(3000):
            try:
                writer.write_now(data[: 37 + n % 300], "RTCMV3")
            except Exception as exc:  # noqa: BLE001 - what the test looks for
                errors.append(repr(exc))
    finally:
        stop.set()
        flipper.join()
        sys.setswitchinterval(interval)
    assert errors == []
    assert conserved(feed) and feed.counts.bytes_written == len(sinks[0]) + len(sinks[1])
    for sink in sinks:                               # whole frames only, on either port
        splitter = Rtcm3Splitter()
        splitter.feed(bytes(sink))
        assert splitter.garbage_bytes == 0 and splitter.pending == 0


def test_attach_waits_for_a_write_in_progress():
    """Nothing lands on a port after attach(None) returned (the port is being set up)."""
    feed = CorrectionsFeed("RTCMV3", None, 1e9)
    writing, release, after_detach = threading.Event(), threading.Event(), []
    detached = threading.Event()

    def slow_port(data):
        writing.set()
        release.wait(5.0)
        after_detach.append(detached.is_set())
    writer = CorrectionsWriter(feed)
    writer.attach(slow_port)
    step = threading.Thread(target=writer.write_now, args=(rtcm3(1004), "RTCMV3"))
    step.start()
    assert writing.wait(5.0)
    detacher = threading.Thread(target=lambda: (writer.attach(None), detached.set()))
    detacher.start()
    assert not detached.wait(0.2)                   # held by the write in progress
    release.set()
    step.join(5.0)
    detacher.join(5.0)
    assert after_detach == [False] and detached.is_set()


def test_a_writer_step_that_raises_is_counted_and_the_thread_lives(caplog):
    feed = CorrectionsFeed("RTCMV3", None, 1e9)
    sent = []
    ticks = []

    def tick():
        ticks.append(1)
        raise RuntimeError("report failed")

    def bug(data):
        raise RuntimeError("not a port error")
    writer = CorrectionsWriter(feed, on_tick=tick)
    writer.attach(bug)
    writer.start()
    try:
        writer.put(rtcm3(1004) + rtcm3(1005, 19)[:10], "RTCMV3")    # a whole frame and a partial one
        assert wait_until(lambda: feed.counts.dropped["internal"] > 0, timeout=5.0)
        assert feed.counts.dropped["internal"] == len(rtcm3(1004)) + 10 and conserved(feed)
        writer.attach(sent.append)
        writer.put(rtcm3(1006, 21), "RTCMV3")
        assert wait_until(lambda: sent == [rtcm3(1006, 21)], timeout=5.0)
        assert wait_until(lambda: len(ticks) >= 2, timeout=5.0)     # ticks that raise, and go on
        assert writer._thread.is_alive() and writer.internal_errors >= 2
    finally:
        writer.stop()
    assert conserved(feed) and feed.counts.bytes_written == len(rtcm3(1006, 21))
    failed = [r for r in caplog.records if "corrections writer" in r.getMessage()]
    assert len(failed) == 1 and failed[0].exc_info is not None      # traceback once, then throttled


def test_raw_samples_larger_than_the_bucket_go_in_pieces():
    """At 9600 baud the bucket holds 1029 bytes: a 1500-byte burst read of RTCM 2.x is not
    lost whole; what fits goes, the rest is dropped, and the line's rate still holds."""
    feed = CorrectionsFeed("RTCM", None, line_bytes_per_s(9600))
    burst = bytes(range(64, 128)) * 24                                # 1536 bytes
    first = feed.take(burst, "RAW", 0.0)
    assert first.data == burst[:1029] and first.flooded
    assert feed.counts.dropped["flood"] == len(burst) - 1029
    second = feed.take(burst, "RAW", 2.0)                             # the bucket is full again
    assert second.data == burst[:1029]
    small = feed.take(burst[:500], "RAW", 2.6)                        # 0.6 s refills 518
    assert small.data == burst[:500] and not small.flooded
    c = feed.counts
    assert c.bytes_in == sum(len(t.data) for t in (first, second, small)) + c.dropped["flood"]
