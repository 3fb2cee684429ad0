"""The VIENA firmware's frames: CRC-8/MAXIM, round trips, and a decoder that survives
anything a serial line can do to a stream. A stream ends with the line falling silent
(`silence()`), which confirms its last frame."""
from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from viena.services.imu.driver import FRAME_SIZE, FrameDecoder, crc8_maxim, decode_frame, encode_frame
from viena.services.imu.driver.crc import TABLE
from viena.services.imu.driver.frames import Frame

FUZZ = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])


def vec(limit: float):
    """Three float32 values within what the firmware can send."""
    f = st.floats(min_value=-limit, max_value=limit, allow_nan=False, width=32)
    return st.tuples(f, f, f)


BANNER = b"Initializing I2C devices...\r\nTesting device connections...\r\nADXL345 connection successful\r\n"


def frames(n: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    return [encode_frame(7, rng.normal(0, 1, 3), rng.normal(0, 20, 3), rng.normal(0, 400, 3),
                         rng.uniform((-180, -90, -180), (180, 90, 180))) for _ in range(n)]


def decode_all(data: bytes, chunk: int = 64) -> tuple[list[bytes], FrameDecoder]:
    d = FrameDecoder()
    out = []
    for k in range(0, len(data), chunk):
        for offset, _frame in d.feed(data[k:k + chunk]):
            out.append(data[offset:offset + FRAME_SIZE])
    for offset, _frame in d.silence():
        out.append(data[offset:offset + FRAME_SIZE])
    return out, d


def decode_with_pauses(units: list[bytes], chunk: int) -> tuple[list[bytes], FrameDecoder]:
    """Each unit's bytes in chunks, then a pause (silence) before the next unit."""
    d = FrameDecoder()
    offsets = []
    for unit in units:
        for k in range(0, len(unit), chunk):
            offsets += [o for o, _ in d.feed(unit[k:k + chunk])]
        offsets += [o for o, _ in d.silence()]
    data = b"".join(units)
    return [data[o:o + FRAME_SIZE] for o in offsets], d


def test_crc8_maxim_check_value_and_the_firmware_table():
    assert crc8_maxim(b"123456789") == 0xA1
    assert crc8_maxim(b"") == 0
    # first and last entries of crc_table_maxim in VIENA-IST/AHRS src/Razor.h
    assert TABLE[:8] == (0x00, 0x5E, 0xBC, 0xE2, 0x61, 0x3F, 0xDD, 0x83)
    assert TABLE[-4:] == (0xD7, 0x89, 0x6B, 0x35)


def test_frame_layout_is_the_firmware_struct():
    data = encode_frame(3, (1, 2, 3), (4, 5, 6), (7, 8, 9), (10, 11, 12))
    assert len(data) == FRAME_SIZE == 52
    sync1, sync2, board, *values, crc = struct.unpack("<2BB12fB", data)
    assert (sync1, sync2, board) == (0xAA, 0xBB, 3)
    assert values == list(range(1, 13))
    assert crc8_maxim(data[:51] + b"\x00") == crc


@given(st.integers(0, 255), vec(18), vec(2300), vec(5e4), st.tuples(*(st.floats(-lim, lim, width=32) for lim in (180, 90, 180))))
@settings(max_examples=200, deadline=None)
def test_frame_round_trip(board, acc, gyr, mag, eul):
    frame = decode_frame(encode_frame(board, acc, gyr, mag, eul))
    assert frame == Frame(board, acc, gyr, mag, eul)


def test_decode_frame_says_what_is_wrong():
    good = encode_frame(1, (0, 0, 1), (0, 0, 0), (1, 2, 3), (0, 0, 0))
    with pytest.raises(ValueError, match="52 bytes"):
        decode_frame(good[:-1])
    with pytest.raises(ValueError, match="not aabb"):
        decode_frame(b"\x00" + good[1:])
    bad = bytearray(good)
    bad[10] ^= 0x40
    with pytest.raises(ValueError, match="bad CRC"):
        decode_frame(bytes(bad))
    with pytest.raises(ValueError, match="out of any sensor's range"):
        decode_frame(encode_frame(1, (float("nan"), 0, 0), (0, 0, 0), (0, 0, 0), (0, 0, 0)))


def test_boot_text_is_kept_as_lines_not_counted_as_garbage():
    stream = frames(5)
    out, d = decode_all(BANNER + b"".join(stream), chunk=7)
    assert out == stream
    assert list(d.text) == ["Initializing I2C devices...", "Testing device connections...",
                            "ADXL345 connection successful"]
    assert (d.stats.frames, d.stats.crc_errors, d.stats.bytes_skipped, d.stats.resyncs) == (5, 0, 0, 0)


@given(st.lists(st.integers(1, 120), min_size=1, max_size=40))
@FUZZ
def test_any_chunking_gives_the_same_frames(cuts):
    stream = frames(12)
    data = BANNER + b"".join(stream)
    d, out, pos = FrameDecoder(), [], 0
    for size in cuts * 20:
        if pos >= len(data):
            break
        out += [data[o:o + FRAME_SIZE] for o, _ in d.feed(data[pos:pos + size])]
        pos += size
    out += [data[o:o + FRAME_SIZE] for o, _ in d.feed(data[pos:]) + d.silence()]
    assert out == stream


def test_a_bad_crc_costs_one_frame_and_is_counted():
    stream = frames(6)
    data = bytearray(b"".join(stream))
    data[2 * FRAME_SIZE + 20] ^= 0x01
    out, d = decode_all(bytes(data))
    assert out == stream[:2] + stream[3:]
    assert d.stats.crc_errors >= 1
    assert d.stats.resyncs == 1
    assert d.stats.bytes_skipped >= FRAME_SIZE - 1


def test_a_half_sync_at_a_chunk_boundary_is_not_lost():
    stream = frames(3)
    data = b"\x00\x13" + b"".join(stream)
    d = FrameDecoder()
    first = d.feed(data[:2 + FRAME_SIZE + 1])     # ends with the next frame's AA
    rest = d.feed(data[2 + FRAME_SIZE + 1:]) + d.silence()
    assert len(first) + len(rest) == 3


damage = st.sampled_from(["flip", "delete", "insert", "truncate", "garbage"])


@given(st.lists(st.tuples(st.integers(0, 29), damage, st.integers(0, 51), st.binary(min_size=1, max_size=80)),
                max_size=6),
       st.integers(1, 200))
@FUZZ
def test_corrupted_streams_never_crash_and_every_clean_frame_comes_back(damages, chunk):
    """Damage frames (bit flips, lost and extra bytes, cut frames, garbage between frames).
    Every intact frame must come back, in order, unless bytes were lost or added right
    before it (then a shifted window may pass the 8-bit CRC by chance, 1 in 256, and
    swallow its start); whatever else comes out has a good CRC, at most one per damage."""
    stream = frames(30, seed=len(damages))
    parts = [bytearray(f) for f in stream]
    before = [b""] * 30
    damaged, reshaped = set(), set()
    for index, kind, pos, junk in damages:
        damaged.add(index)
        if kind != "flip":
            reshaped.add(index)
        f = parts[index]
        pos = min(pos, len(f) - 1)
        if pos < 0:
            continue
        if kind == "flip":
            f[pos] ^= junk[0] or 0x80
        elif kind == "delete":
            del f[pos]
        elif kind == "insert":
            f[pos:pos] = junk
        elif kind == "truncate":
            del f[pos:]
        else:
            before[index] = junk
    # as the firmware sends them: each frame (and what the line did to it) at once, then
    # the line idle until the next one (1 ms of bytes, 11 ms of pause at 82.5 Hz)
    units = [before[i] + bytes(parts[i]) for i in range(30)]
    out, d = decode_with_pauses(units, chunk)
    clean = [stream[i] for i in range(30)
             if i not in damaged and (i == 0 or i - 1 not in reshaped) and not before[i]]
    recovered = [f for f in out if f in stream]
    assert recovered == sorted(recovered, key=stream.index)           # in order, no repeats
    assert set(clean) <= set(recovered)
    strays = [f for f in out if f not in stream]
    assert len(strays) <= len(damages)
    for f in out:
        decode_frame(f)                                                  # CRC and ranges hold
    assert d.stats.frames == len(out)


@given(st.binary(max_size=2000))
@FUZZ
def test_random_bytes_never_crash_the_decoder(data):
    d = FrameDecoder()
    for k in range(0, len(data), 97):
        for _offset, frame in d.feed(data[k:k + 97]):
            assert isinstance(frame, Frame)
    assert d.stats.bytes_skipped <= len(data)
