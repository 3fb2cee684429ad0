"""OEM4 binary framing: sync, 28-byte header, body, CRC32 (vol. 2 §1.1.3, §1.6).

The decoder is incremental and never trusts a byte it has not checked: every frame's
CRC is verified before it is returned, a frame that fails is dropped and the search for
the next sync resumes one byte after the failed sync, so a corrupted length field can
never swallow the good frames behind it.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field, replace

from .enums import MessageFormat, Port, TimeStatus

SYNC = b"\xaa\x44\x12"
HEADER_LENGTH = 28
CRC_LENGTH = 4
#: Bodies longer than this are treated as a corrupted length (the largest OEM4 logs,
#: RANGE and ALMANAC with all channels, stay under 4 kB).
MAX_BODY_LENGTH = 8192

RESPONSE_BIT = 0x80
#: Message type byte of binary messages as the receiver sends them and as the manual's
#: examples write commands (Table 6): format bits 00 (binary), reserved bits 00010.
BINARY_MESSAGE_TYPE = 0x02

# sync(3) | hdr len u8 | msg id u16 | msg type u8 | port u8 | msg len u16 | sequence u16 |
# idle u8 | time status u8 | week u16 | ms u32 | rx status u32 | reserved u16 | sw u16
_HEADER = struct.Struct("<3sBHBBHHBBHLLHH")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<L")


def crc32(data) -> int:
    """NovAtel's CRC-32 (reflected 0xEDB88320, init 0, no final xor) via zlib.

    zlib's crc32 starts from ~value and complements its result; starting it from
    0xFFFFFFFF and complementing again gives the receiver's init-0, no-xor variant.
    """
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


@dataclass(frozen=True, slots=True)
class Header:
    """The binary message header (Table 4)."""

    message_id: int
    message_type: int = BINARY_MESSAGE_TYPE
    port_address: int = Port.THISPORT
    length: int = 0                 # body length, excluding header and CRC
    sequence: int = 0
    idle_time: int = 0              # 0..200, half-percent units
    time_status: int = 0            # TimeStatus; 0 = "invalid, ignore the time fields"
    week: int = 0
    milliseconds: int = 0
    receiver_status: int = 0
    reserved: int = 0
    sw_version: int = 0
    header_length: int = HEADER_LENGTH

    @property
    def is_response(self) -> bool:
        return bool(self.message_type & RESPONSE_BIT)

    @property
    def message_format(self) -> MessageFormat:
        return MessageFormat((self.message_type >> 5) & 0x3)

    @property
    def idle_percent(self) -> float:
        return self.idle_time / 2.0

    @property
    def time_status_enum(self) -> TimeStatus:
        return TimeStatus(self.time_status)

    def pack(self) -> bytes:
        return _HEADER.pack(SYNC, HEADER_LENGTH, self.message_id, self.message_type,
                            self.port_address, self.length, self.sequence, self.idle_time,
                            self.time_status, self.week, self.milliseconds,
                            self.receiver_status, self.reserved, self.sw_version)


@dataclass(frozen=True, slots=True)
class Frame:
    """One received frame whose CRC checked out."""

    header: Header
    body: bytes
    raw: bytes = field(repr=False)
    t_host_ns: int = 0              # host clock when the frame's last byte was read


def unpack_header(buf, offset: int = 0) -> Header:
    """The header at ``offset`` (its sync is not checked here)."""
    fields = _HEADER.unpack_from(buf, offset)
    return Header(*fields[2:], header_length=fields[1])


def encode_frame(header: Header, body: bytes = b"") -> bytes:
    """Header (with its length set to the body's) + body + CRC."""
    if header.length != len(body):
        header = replace(header, length=len(body))
    data = header.pack() + body
    return data + _U32.pack(crc32(data))


@dataclass
class DecoderStats:
    """What the decoder has seen; every error kind counted on its own."""

    frames: int = 0
    crc_errors: int = 0
    length_errors: int = 0          # header length < 28 or body length beyond the limit
    resyncs: int = 0                # times sync was regained after bytes were skipped
    discarded_bytes: int = 0


_NEED_MORE, _BAD_LENGTH, _BAD_CRC = -1, -2, -3


class FrameDecoder:
    """Bytes in, CRC-checked frames out; keeps the partial frame between calls."""

    def __init__(self, max_body_length: int = MAX_BODY_LENGTH):
        self.max_body_length = max_body_length
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._lost = False          # bytes were skipped since the last good frame

    def reset(self) -> None:
        """Forget the partial frame (the port was reopened)."""
        self._buf.clear()
        self._lost = False

    def feed(self, data: bytes, t_host_ns: int = 0) -> list[Frame]:
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        stats = self.stats
        n = len(buf)
        pos = 0
        while n - pos >= 3:
            if buf[pos] != 0xAA or buf[pos + 1] != 0x44 or buf[pos + 2] != 0x12:
                nxt = buf.find(SYNC, pos + 1)
                if nxt < 0:
                    # keep a tail that may be the start of the next sync
                    nxt = n - 2 if buf[n - 2:] == SYNC[:2] else (n - 1 if buf[n - 1] == 0xAA else n)
                self._skip(nxt - pos)
                pos = nxt
                continue
            end = self._frame_end(buf, pos, n)
            if end == _NEED_MORE:
                # A corrupted length can claim kilobytes; if a whole good frame already
                # follows, this header was not one: do not sit on the good frame.
                if self._good_frame_after(buf, pos, n):
                    stats.length_errors += 1
                    self._skip(1)
                    pos += 1
                    continue
                break
            if end < 0:
                if end == _BAD_LENGTH:
                    stats.length_errors += 1
                else:
                    stats.crc_errors += 1
                self._skip(1)
                pos += 1
                continue
            header = unpack_header(buf, pos)
            raw = bytes(buf[pos:end])
            frames.append(Frame(header, raw[header.header_length:-CRC_LENGTH], raw, t_host_ns))
            stats.frames += 1
            if self._lost:
                stats.resyncs += 1
                self._lost = False
            pos = end
        if pos:
            del buf[:pos]
        return frames

    def _frame_end(self, buf: bytearray, pos: int, n: int) -> int:
        """End of the CRC-checked frame whose sync is at pos, or why there is none."""
        if n - pos < 10:
            return _NEED_MORE
        header_length = buf[pos + 3]
        body_length = _U16.unpack_from(buf, pos + 8)[0]
        if header_length < HEADER_LENGTH or body_length > self.max_body_length:
            return _BAD_LENGTH
        end = pos + header_length + body_length
        if n < end + CRC_LENGTH:
            return _NEED_MORE
        view = memoryview(buf)
        try:
            ok = crc32(view[pos:end]) == _U32.unpack_from(buf, end)[0]
        finally:
            view.release()
        return end + CRC_LENGTH if ok else _BAD_CRC

    def _good_frame_after(self, buf: bytearray, pos: int, n: int) -> bool:
        q = buf.find(SYNC, pos + 1)
        while q >= 0:
            if self._frame_end(buf, q, n) >= 0:
                return True
            q = buf.find(SYNC, q + 1)
        return False

    def _skip(self, count: int) -> None:
        if count > 0:
            self.stats.discarded_bytes += count
            self._lost = True
