"""The car's custom Razor firmware (VIENA-IST/AHRS): 52-byte binary frames after boot text.

    AA BB | id u8 | accel f32[3] g | gyro f32[3] deg/s | mag f32[3] counts |
    euler f32[3] deg (yaw, pitch, roll) | crc8 u8            struct '<2BB12fB', little endian

The CRC-8/MAXIM covers the whole 52-byte struct with the CRC byte zeroed. Axes are the
board's as printed (on the car: x right, y forward, z up). The firmware has no command
interface: after reset it prints a few ASCII lines, then streams frames at about 82.5 Hz.

An 8-bit CRC passes one misaligned window in 256: after a frame cut short, the 52 bytes from
its sync (the cut frame's start and the next frame's) pass by chance often enough to publish
nonsense. So `FrameDecoder` accepts a frame only when three things hold:

1. its CRC checks;
2. its values are physically possible for the sensors (see LIMITS);
3. the bytes that follow it start the next frame (AA BB), or the line falls silent right
   after it (`silence()`, for the last frame of a burst).

A cut frame's window ends inside the next frame, so what follows it is that frame's data,
not a sync, and it is refused; the next frame's own sync is then found inside the refused
window. Silence cannot confirm a window that holds a sync of its own (a cut frame and the
start of the next), so it waits for more bytes instead. Refusals are counted by reason.
The decoder also takes chunks of any size and skips the boot text (keeping its lines).
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

#: What the board can physically send, per value (lowest, highest):
#: - accel, g: the ADXL345's 13 bits (+-4096 LSB at +-16 g) at its lowest datasheet
#:   sensitivity, 230 LSB/g (4.3 mg/LSB), through the EEPROM line: 17.8 g;
#: - gyro, deg/s: the ITG-3200's int16 at 14.375 LSB per deg/s (2279.5), less the boot bias;
#: - mag, counts: the HMC5843's int16 registers (12-bit readings, but a register read
#:   mid-update spans all 16 bits: the car's recordings hold -19458) through the EEPROM
#:   3x3 transform and offset;
#: - euler, deg: yaw by either convention of the firmware's Madgwick (-180..180 or
#:   0..360), pitch from an arcsine, roll from an arctangent.
LIMITS = ((-18.0, 18.0),) * 3 + ((-2300.0, 2300.0),) * 3 + ((-5.0e4, 5.0e4),) * 3 + (
    (-180.01, 360.01), (-90.01, 90.01), (-180.01, 180.01))

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
    crc_errors: int = 0        # AA BB candidates whose CRC did not check
    out_of_range: int = 0      # CRC checked, but a value no sensor can send
    unconfirmed: int = 0       # CRC and values fine, but what followed did not start a frame
    resyncs: int = 0           # times the stream was found again after losing it
    bytes_skipped: int = 0     # bytes that were neither a good frame nor a line of text
    text_lines: int = 0
    by_silence: int = 0        # frames confirmed by the line falling silent after them


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
    v = _PAYLOAD.unpack_from(data, start + 2)
    for x, (lo, hi) in zip(v[1:], LIMITS):
        if not lo <= x <= hi:                  # also false for nan
            return None
    return Frame(v[0], v[1:4], v[4:7], v[7:10], v[10:13])


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


_WAIT = object()        # a candidate that needs the bytes after it (or silence) to be judged


class FrameDecoder:
    """Bytes in, (stream offset, Frame) out. Never raises on bad input: it counts it.

    `feed(data)` returns the frames its bytes confirm; `silence()` (the caller's: no byte
    for a frame time) returns a complete frame that was waiting for the next one's start.
    `waiting` says whether there is such a frame. A refused candidate is searched again
    from its second byte, so a refusal costs no good frame behind it; the stream offset
    of each frame lets the host count lost frame slots.
    """

    def __init__(self, text_lines_kept: int = 20):
        self.stats = DecoderStats()
        self.text: deque[str] = deque(maxlen=text_lines_kept)   # recent lines of text from the board
        self._buf = bytearray()
        self._base = 0             # stream offset of self._buf[0]
        self._lost = False         # bytes were lost since the last good frame
        self._ever_locked = False  # a first lock is an acquisition, later ones are resyncs
        self._waiting = False      # a complete candidate waits at the buffer's start
        self._silence_refused = False   # ... and silence could not confirm it
        #: the last candidate whose CRC and values checked, (stream offset, frame): a frame that
        #: waited for the bytes after it is judged again, without checking them twice
        self._checked: tuple[int, Frame] | None = None

    @property
    def waiting(self) -> bool:
        """A complete frame waits for the bytes after it; silence may confirm it."""
        return self._waiting and not self._silence_refused

    def reset(self) -> None:
        """Forget buffered bytes and restart stream offsets (a new connection); the
        counters keep running."""
        self._buf.clear()
        self._base = 0
        self._lost = self._ever_locked = self._waiting = self._silence_refused = False
        self._checked = None

    def feed(self, data: bytes | bytearray) -> list[tuple[int, Frame]]:
        self._buf += data
        if data:
            self._silence_refused = False
        return self._scan(silent=False)

    def silence(self) -> list[tuple[int, Frame]]:
        """The line has been quiet for a frame time: judge the waiting frame without the
        bytes after it."""
        return self._scan(silent=True)

    def _scan(self, silent: bool) -> list[tuple[int, Frame]]:
        buf = self._buf
        out: list[tuple[int, Frame]] = []
        n = len(buf)
        i = 0
        self._waiting = False
        while True:
            if n - i < 2 or buf[i] != 0xAA or buf[i + 1] != 0xBB:
                j = buf.find(SYNC, i)
                if j < 0:
                    # keep a trailing AA (half a sync) and an unfinished line of text
                    keep = n - 1 if n > i and buf[-1] == 0xAA else n
                    keep = self._partial_line_start(buf, i, keep)
                    self._skip(buf, i, keep)
                    i = keep
                    break
                self._skip(buf, i, j)
                i = j
            if n - i < FRAME_SIZE:
                break
            verdict = self._judge(buf, i, n, silent)
            if verdict is _WAIT:
                self._waiting = True
                break
            if verdict is None:                  # refused: look again from the next byte
                self.stats.bytes_skipped += 1
                self._lost = True
                i += 1
                continue
            if self._lost and self._ever_locked:
                self.stats.resyncs += 1
            self._lost = False
            self._ever_locked = True
            out.append((self._base + i, verdict))
            self.stats.frames += 1
            i += FRAME_SIZE
        if i:
            del buf[:i]
            self._base += i
        return out

    def _judge(self, buf: bytearray, i: int, n: int, silent: bool):
        """The frame whose sync is at i, None if it is refused (counted), or _WAIT."""
        stats = self.stats
        at = self._base + i
        checked = self._checked
        if checked is not None and checked[0] == at:
            frame = checked[1]
        else:
            if not frame_crc_ok(buf, i):
                stats.crc_errors += 1
                return None
            unpacked = _unpack(buf, i)
            if unpacked is None:
                stats.out_of_range += 1
                return None
            frame = unpacked
            self._checked = (at, frame)
        after = i + FRAME_SIZE
        if n - after >= 2:
            if buf[after] == 0xAA and buf[after + 1] == 0xBB:
                return frame
            stats.unconfirmed += 1
            return None
        if n - after == 1 and buf[after] != 0xAA:
            stats.unconfirmed += 1
            return None
        if not silent:
            return _WAIT
        if buf.find(SYNC, i + 1, after) >= 0:
            # a frame may start inside this one: it may be a cut frame and the start of
            # the next, so only the bytes to come can tell
            self._silence_refused = True
            return _WAIT
        stats.by_silence += 1
        return frame

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
