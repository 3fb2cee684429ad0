"""The car's custom Razor firmware (VIENA-IST/AHRS): 52-byte binary frames after boot text.

    AA BB | id u8 | accel f32[3] g | gyro f32[3] deg/s | mag f32[3] counts |
    euler f32[3] deg (yaw, pitch, roll) | crc8 u8            struct '<2BB12fB', little endian

The CRC-8/MAXIM covers the whole 52-byte struct with the CRC byte zeroed. Axes are the
board's as printed (on the car: x right, y forward, z up). The firmware has no command
interface: after reset it prints a few ASCII lines, then streams frames at about 82.5 Hz.

`FrameDecoder` takes the byte stream in chunks of any size, skips the boot text (keeping
its lines), checks every CRC, and after a bad frame hunts for the next AA BB.
"""
from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

from viena.services.imu.driver.crc import TABLE, crc8_maxim

SYNC = b"\xaa\xbb"
FRAME = struct.Struct("<2BB12fB")
FRAME_SIZE = FRAME.size            # 52
_PAYLOAD = struct.Struct("<B12f")  # id + floats, read in place from the stream buffer

# What the firmware can possibly send (ADXL345 +-16 g, ITG-3200 +-2000 deg/s, HMC5843
# int16 counts through a 3x3 EEPROM transform, angles). Beyond these a frame whose CRC
# matched by chance (1 in 256 while hunting through garbage) is still rejected.
_LIMITS = (64.0,) * 3 + (4000.0,) * 3 + (1.0e5,) * 3 + (720.0,) * 3

#: Printable ASCII plus tab, CR: what the boot text is made of.
_TEXT_BYTES = frozenset(range(0x20, 0x7F)) | {0x09, 0x0D}
MAX_TEXT_LINE = 160


class Frame(NamedTuple):
    """One sensor frame, in the board's axes and the firmware's units."""

    board_id: int | None           # EEPROM byte 0 (None: the stock firmware has no id)
    accel_g: tuple[float, float, float]
    gyro_dps: tuple[float, float, float]
    mag_counts: tuple[float, float, float]
    euler_deg: tuple[float, float, float] | None   # firmware's yaw, pitch, roll: not to be trusted


@dataclass
class DecoderStats:
    """What the decoder has seen since it was made; the service reports these as health."""

    frames: int = 0
    crc_errors: int = 0        # AA BB candidates whose CRC (or value range) did not check
    resyncs: int = 0           # times the stream was found again after losing it
    bytes_skipped: int = 0     # bytes that were neither a good frame nor a line of text
    text_lines: int = 0


def encode_frame(board_id: int, accel_g, gyro_dps, mag_counts, euler_deg) -> bytes:
    """A frame exactly as the firmware sends it, CRC included."""
    body = FRAME.pack(0xAA, 0xBB, board_id, *accel_g, *gyro_dps, *mag_counts, *euler_deg, 0)
    return body[:-1] + bytes((crc8_maxim(body),))


def frame_crc_ok(data: bytes | bytearray, start: int = 0) -> bool:
    """CRC over the 52 bytes at `start` with the CRC byte taken as zero."""
    crc = crc8_maxim(data[start:start + FRAME_SIZE - 1])
    return TABLE[crc] == data[start + FRAME_SIZE - 1]


def _unpack(data: bytes | bytearray, start: int) -> Frame | None:
    """The frame at `start` (CRC already checked), or None if its values are impossible."""
    board_id, *v = _PAYLOAD.unpack_from(data, start + 2)
    for x, limit in zip(v, _LIMITS):
        if not -limit <= x <= limit:           # also false for nan
            return None
    return Frame(board_id, tuple(v[0:3]), tuple(v[3:6]), tuple(v[6:9]), tuple(v[9:12]))


def decode_frame(data: bytes) -> Frame:
    """Decode exactly one 52-byte frame; ValueError says what is wrong with it."""
    if len(data) != FRAME_SIZE:
        raise ValueError(f"a frame is {FRAME_SIZE} bytes, got {len(data)}")
    if data[:2] != SYNC:
        raise ValueError(f"frame starts with {data[:2].hex()}, not aabb")
    if not frame_crc_ok(data):
        raise ValueError(f"bad CRC: frame says {data[-1]:#04x}, "
                         f"content gives {TABLE[crc8_maxim(data[:-1])]:#04x}")
    frame = _unpack(data, 0)
    if frame is None:
        raise ValueError("CRC matches but values are out of any sensor's range")
    return frame


class FrameDecoder:
    """Bytes in, (stream offset, Frame) out. Never raises on bad input: it counts it.

    While locked, frames follow each other back to back and are checked in place; a
    frame that fails drops the decoder into hunting, where it scans for AA BB, takes
    complete lines of printable ASCII as text (the boot banner) and counts the rest as
    skipped. The stream offset of each frame lets the host count lost frame slots.
    """

    def __init__(self, text_lines_kept: int = 20):
        self.stats = DecoderStats()
        self.text = deque(maxlen=text_lines_kept)   # recent lines of text from the board
        self._buf = bytearray()
        self._base = 0             # stream offset of self._buf[0]
        self._locked = False
        self._lost = False         # bytes were lost since the last good frame
        self._ever_locked = False  # a first lock is an acquisition, later ones are resyncs

    @property
    def locked(self) -> bool:
        return self._locked

    def reset(self) -> None:
        """Forget buffered bytes and restart stream offsets (a new connection); the
        counters keep running."""
        self._buf.clear()
        self._base = 0
        self._locked = self._lost = self._ever_locked = False

    def feed(self, data: bytes | bytearray) -> list[tuple[int, Frame]]:
        buf = self._buf
        buf += data
        out: list[tuple[int, Frame]] = []
        n = len(buf)
        i = 0
        stats = self.stats
        while True:
            if self._locked:
                if n - i < FRAME_SIZE:
                    break
                if buf[i] == 0xAA and buf[i + 1] == 0xBB and frame_crc_ok(buf, i):
                    frame = _unpack(buf, i)
                    if frame is not None:
                        out.append((self._base + i, frame))
                        stats.frames += 1
                        i += FRAME_SIZE
                        continue
                self._locked = False       # hunting looks at the same bytes again
                self._lost = True
            j = buf.find(SYNC, i)
            if j < 0:
                # keep a trailing AA (half a sync) and an unfinished line of text
                keep = n - 1 if n and buf[-1] == 0xAA else n
                keep = self._partial_line_start(buf, i, keep)
                self._skip(buf, i, keep)
                i = keep
                break
            self._skip(buf, i, j)
            i = j
            if n - i < FRAME_SIZE:
                break
            frame = _unpack(buf, i) if frame_crc_ok(buf, i) else None
            if frame is None:
                stats.crc_errors += 1
                stats.bytes_skipped += 1
                self._lost = True
                i += 1
                continue
            if self._lost and self._ever_locked:
                stats.resyncs += 1
            self._lost = False
            self._locked = self._ever_locked = True
            out.append((self._base + i, frame))
            stats.frames += 1
            i += FRAME_SIZE
        if i:
            del buf[:i]
            self._base += i
        return out

    # -- text and garbage between frames -----------------------------------------------------
    def _skip(self, buf: bytearray, start: int, end: int) -> None:
        """Account for buf[start:end]: complete printable lines are text, the rest skipped."""
        if start >= end:
            return
        skipped = 0
        pos = start
        while pos < end:
            nl = buf.find(b"\n", pos, end)
            stop = end if nl < 0 else nl + 1
            chunk = buf[pos:stop]
            if nl >= 0 and len(chunk) <= MAX_TEXT_LINE and _is_text(chunk[:-1]):
                line = chunk.decode("ascii").strip()
                if line:
                    self.text.append(line)
                    self.stats.text_lines += 1
            else:
                skipped += len(chunk)
            pos = stop
        if skipped:
            self.stats.bytes_skipped += skipped
            self._lost = True

    @staticmethod
    def _partial_line_start(buf: bytearray, start: int, end: int) -> int:
        """Where an unfinished line of text at the end of buf[start:end] begins (or end)."""
        nl = buf.rfind(b"\n", start, end)
        tail = nl + 1 if nl >= 0 else start
        if end - tail < MAX_TEXT_LINE and _is_text(buf[tail:end]):
            return tail
        return end


def _is_text(chunk: bytes | bytearray) -> bool:
    return all(b in _TEXT_BYTES for b in chunk)
