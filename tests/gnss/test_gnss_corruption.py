"""Corrupted streams: flipped bits, truncated frames, garbage between frames, absurd
length fields. Nothing bad is ever emitted, every untouched frame still comes through,
and each kind of damage is counted."""
from __future__ import annotations

import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from viena.services.gnss.driver.gpstime import gps_to_utc_ns
from viena.services.gnss.driver.nmea import NmeaDecoder
from viena.services.gnss.driver.novatel import (
    BestXyz,
    FrameDecoder,
    Header,
    PositionType,
    Response,
    SolutionStatus,
    encode_log,
)
from viena.services.gnss.driver.novatel.framing import MAX_BODY_LENGTH
from viena.services.gnss.simulator.nmea_twin import nmea_epoch
from viena.services.gnss.simulator.solution import Solution

FUZZ = settings(max_examples=100, deadline=None, derandomize=True)


def bestxyz_frame(i: int) -> bytes:
    data = BestXyz(SolutionStatus.SOL_COMPUTED, PositionType.SINGLE,
                   (4918535.0 + i, -791215.0 - i, 3969669.0 + i / 7), (1.5, 1.5, 2.5),
                   SolutionStatus.SOL_COMPUTED, PositionType.DOPPLER_VELOCITY,
                   (0.1 * i, 0.0, -0.1), (0.03,) * 3, "", 0.15, 0.0, 0.0, 8, 7)
    return encode_log(Header(0, week=1877, milliseconds=100 * i, time_status=180), data)


def response_frame(i: int) -> bytes:
    return Response(1, "OK").frame(Header(1, sequence=i))


FRAMES = [bestxyz_frame(i) if i % 5 else response_frame(i) for i in range(12)]

damage = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10_000), st.integers(0, 7)),
    st.tuples(st.just("truncate"), st.integers(1, 10_000)),
    st.tuples(st.just("garbage"), st.binary(min_size=1, max_size=40)),
    st.tuples(st.just("sync-garbage"), st.binary(max_size=30)),
    st.tuples(st.just("length"), st.integers(0, 0xFFFF)),
)


def corrupt(frame: bytes, op) -> bytes:
    kind = op[0]
    if kind == "flip":
        b = bytearray(frame)
        b[op[1] % len(b)] ^= 1 << op[2]
        return bytes(b)
    if kind == "truncate":
        return frame[:op[1] % len(frame)]
    if kind == "garbage":
        return op[1] + frame
    if kind == "sync-garbage":                  # something that starts like a frame
        return b"\xaa\x44\x12" + op[1] + frame
    b = bytearray(frame)
    struct.pack_into("<H", b, 8, op[1])
    return bytes(b)


@FUZZ
@given(plan=st.lists(st.one_of(st.none(), damage), min_size=len(FRAMES), max_size=len(FRAMES)),
       chunks=st.lists(st.integers(1, 300), min_size=1, max_size=40))
def test_only_intact_frames_come_out_and_all_of_them(plan, chunks):
    stream, intact = b"", []
    for frame, op in zip(FRAMES, plan):
        if op is None:
            stream += frame
            intact.append(frame)
            continue
        damaged = corrupt(frame, op)
        stream += damaged
        if damaged.endswith(frame):             # garbage before an unharmed frame
            intact.append(frame)
    decoder = FrameDecoder()
    out, pos, i = [], 0, 0
    while pos < len(stream):
        size = chunks[i % len(chunks)]
        out += decoder.feed(stream[pos:pos + size])
        pos, i = pos + size, i + 1
    # quiet padding so a damaged header claiming a long body is given its bytes and fails
    out += decoder.feed(bytes(MAX_BODY_LENGTH + 64))
    raws = [f.raw for f in out]
    assert raws == intact                       # nothing invented, nothing good lost
    st_ = decoder.stats
    assert st_.frames == len(intact)
    if any(op is not None and op[0] == "flip" and corrupt(f, op) != f
           for f, op in zip(FRAMES, plan)):
        assert st_.crc_errors + st_.length_errors + st_.discarded_bytes > 0


def test_each_kind_of_damage_is_counted():
    good = bestxyz_frame(1)
    flipped = bytearray(good)
    flipped[60] ^= 0x10
    absurd = bytearray(good)
    struct.pack_into("<H", absurd, 8, 60000)
    decoder = FrameDecoder()
    frames = decoder.feed(b"junk" + good + bytes(flipped) + good + bytes(absurd) + good)
    assert [f.raw for f in frames] == [good, good, good]
    s = decoder.stats
    assert (s.crc_errors, s.length_errors) == (1, 1)
    assert s.resyncs == 3                       # after the junk, the bad CRC, the bad length
    assert s.discarded_bytes == 4 + len(good) + len(good)


def test_a_frame_split_anywhere_is_still_one_frame():
    good = bestxyz_frame(3)
    for cut in range(1, len(good)):
        decoder = FrameDecoder()
        assert decoder.feed(good[:cut]) == []
        assert [f.raw for f in decoder.feed(good[cut:])] == [good]


# -- NMEA ------------------------------------------------------------------------------


def nmea_stream(epochs: int) -> tuple[bytes, dict]:
    """Sentences of consecutive epochs and each epoch's true (lat, lon, height)."""
    out, truth = b"", {}
    base_ms = 1877 * 604_800_000 + 36_000_000
    for i in range(epochs):
        ecef = (4918535.0 + 3 * i, -791215.0, 3969669.0 - 2 * i)
        sol = Solution(base_ms + 100 * i, SolutionStatus.SOL_COMPUTED, PositionType.SINGLE,
                       ecef, (1.0,) * 3, SolutionStatus.SOL_COMPUTED, PositionType.SINGLE,
                       (1.0, 0.5, 0.0), (0.1,) * 3, sats_used=8, sats_tracked=10,
                       undulation_m=55.0)
        utc_ns = gps_to_utc_ns(*divmod(sol.gps_ms, 604_800_000))
        out += nmea_epoch(sol, utc_ns)
        truth[utc_ns] = sol.geodetic()
    return out, truth


NMEA_STREAM = nmea_stream(5)


@FUZZ
@given(flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 6)), max_size=6),
       garbage=st.lists(st.tuples(st.integers(0, 10**6), st.binary(min_size=1, max_size=20)),
                        max_size=3),
       chunk=st.integers(1, 200))
def test_nmea_never_emits_a_corrupted_position(flips, garbage, chunk):
    stream, truth = NMEA_STREAM
    b = bytearray(stream)
    for pos, bit in flips:                      # one flipped bit per sentence at most
        b[pos % len(b)] ^= 1 << bit
    for pos, junk in garbage:
        at = pos % len(b)
        b[at:at] = junk
    decoder = NmeaDecoder()
    fixes = []
    t_host = min(truth)                         # the host's clock: the date without RMC
    for i in range(0, len(b), chunk):
        fixes += decoder.feed(bytes(b[i:i + chunk]), t_host)
    for fix in fixes:
        assert fix.utc_ns in truth, f"epoch {fix.utc_ns} was never sent"
        lat, lon, h = truth[fix.utc_ns]
        assert abs(fix.lat_deg - lat) < 1e-6 and abs(fix.lon_deg - lon) < 1e-6
        assert abs(fix.height_m - h) < 0.06


def test_nmea_checksum_errors_are_counted_and_dropped():
    stream, truth = nmea_stream(3)
    lines = stream.split(b"\r\n")
    gga = next(i for i, line in enumerate(lines) if line.startswith(b"$GPGGA"))
    lines[gga] = lines[gga].replace(b",N,", b",S,")
    decoder = NmeaDecoder()
    fixes = decoder.feed(b"\r\n".join(lines))
    assert decoder.stats.checksum_errors == 1
    assert len(fixes) == 2 and decoder.stats.incomplete_epochs == 1
    assert all(f.lat_deg > 0 for f in fixes)
