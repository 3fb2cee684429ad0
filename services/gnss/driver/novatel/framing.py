"""OEM4 binary framing: sync, 28-byte header, body, CRC32 (vol. 2 §1.1.3, §1.6).

Written out in docs/sensors.md#novatel-oem4-binary-framing and docs/sensors.md#crc-32; the
manual's section and table numbers are OEM4 vol. 2's (docs/README.md#sources).

The decoder is incremental and never trusts a byte it has not checked: every frame's
CRC is verified before it is returned, a frame that fails is dropped and the search for
the next sync resumes one byte after the failed sync, so a corrupted length field can
never swallow the good frames behind it. Between binary frames it also takes the ASCII
messages the receiver sends when asked for a log in ASCII (`#...*crc` CR LF, §1.1.1),
checked by the same CRC, as `AsciiFrame`s (ascii.py reads them).
"""
from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field

from .enums import MessageFormat, Port, TimeStatus

SYNC = b"\xaa\x44\x12"
HEADER_LENGTH = 28
CRC_LENGTH = 4
#: Bodies longer than this are treated as a corrupted length (the largest OEM4 logs,
#: RANGE and ALMANAC with all channels, stay under 4 kB).
MAX_BODY_LENGTH = 8192

#: An ASCII message: '#', printable text, '*', 8 hex digits of CRC, CR LF (§1.1.1).
ASCII_SYNC = b"#"
_PRINTABLE = re.compile(rb"[\x20-\x7e]*")
#: Longer than any ASCII log viena asks for (RXCONFIG's longest lines are a few hundred).
MAX_ASCII_LENGTH = 4096

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

    def pack(self, length: int | None = None) -> bytes:
        """The header's bytes; with `length`, as if its body length were that."""
        return pack_header(self.message_id, self.message_type, self.port_address,
                           self.length if length is None else length, self.sequence, self.idle_time,
                           self.time_status, self.week, self.milliseconds,
                           self.receiver_status, self.reserved, self.sw_version)


def pack_header(message_id: int, message_type: int, port_address: int, length: int, sequence: int,
                idle_time: int, time_status: int, week: int, milliseconds: int, receiver_status: int = 0,
                reserved: int = 0, sw_version: int = 0) -> bytes:
    """The bytes of a Header of these fields (its fields' order) without making one: a
    receiver's twin writes a few every epoch."""
    return _HEADER.pack(SYNC, HEADER_LENGTH, message_id, message_type, port_address, length, sequence,
                        idle_time, time_status, week, milliseconds, receiver_status, reserved, sw_version)


@dataclass(frozen=True, slots=True)
class Frame:
    """One received frame whose CRC checked out."""

    header: Header
    body: bytes
    raw: bytes = field(repr=False)
    t_host_ns: int = 0              # host clock when the frame's last byte was read


@dataclass(frozen=True, slots=True)
class AsciiFrame:
    """One received ASCII message whose CRC checked out: its text from the name to the
    last field (between '#' and '*')."""

    text: str
    t_host_ns: int = 0


def unpack_header(buf, offset: int = 0) -> Header:
    """The header at ``offset`` (its sync is not checked here)."""
    fields = _HEADER.unpack_from(buf, offset)
    return Header(*fields[2:], header_length=fields[1])  # type: ignore[misc]  # fields[2:] stop before it


def encode_frame(header: Header, body: bytes = b"") -> bytes:
    """Header (with its length set to the body's) + body + CRC."""
    return frame_of(header.pack(len(body)), body)


def frame_of(header: bytes, body: bytes) -> bytes:
    """A packed header (its length the body's) + body + CRC."""
    data = header + body
    return data + _U32.pack(crc32(data))


@dataclass
class DecoderStats:
    """What the decoder has seen; every error kind counted on its own."""

    frames: int = 0
    crc_errors: int = 0
    length_errors: int = 0          # header length < 28 or body length beyond the limit
    resyncs: int = 0                # times sync was regained after bytes were skipped
    discarded_bytes: int = 0
    ascii_messages: int = 0         # ASCII messages with a good CRC (also in `frames`)


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

    def feed(self, data: bytes, t_host_ns: int = 0) -> list[Frame | AsciiFrame]:
        buf = self._buf
        buf += data
        frames: list[Frame | AsciiFrame] = []
        stats = self.stats
        n = len(buf)
        pos = 0
        while n - pos >= 3:
            if buf[pos] == 0x23:                               # '#': an ASCII message?
                end = self._ascii_end(buf, pos, n)
                if end == _NEED_MORE:
                    break
                if end < 0:
                    self._skip(1)
                    pos += 1
                    continue
                text = bytes(buf[pos + 1:end]).rstrip(b"\r\n")[:-9]            # without *crc
                frames.append(AsciiFrame(text.decode("ascii"), t_host_ns))
                self._found()
                stats.ascii_messages += 1
                pos = end
                continue
            if buf[pos] != 0xAA or buf[pos + 1] != 0x44 or buf[pos + 2] != 0x12:
                nxt = _next_start(buf, pos + 1)
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
            self._found()
            pos = end
        if pos:
            del buf[:pos]
        return frames

    def _found(self) -> None:
        self.stats.frames += 1
        if self._lost:
            self.stats.resyncs += 1
            self._lost = False

    def _ascii_end(self, buf: bytearray, pos: int, n: int) -> int:
        """End (after CR LF) of the ASCII message whose '#' is at pos, or why there is none:
        a byte that is not printable before the line ends means it is not one."""
        text_end = _PRINTABLE.match(buf, pos + 1).end()  # type: ignore[union-attr]  # `*` always matches
        if text_end - pos > MAX_ASCII_LENGTH:
            return _BAD_LENGTH
        if text_end == n or (buf[text_end] == 0x0D and text_end + 1 == n):
            return _NEED_MORE
        end = text_end + 2 if buf[text_end] == 0x0D else text_end + 1
        if buf[end - 1] != 0x0A:
            return _BAD_LENGTH
        text = buf[pos + 1:text_end]
        star = text_end - pos - 1 - 9
        if star < 0 or text[star] != 0x2A:
            return _BAD_LENGTH
        try:
            crc = int(text[star + 1:], 16)
        except ValueError:
            return _BAD_LENGTH
        if crc32(text[:star]) != crc:
            self.stats.crc_errors += 1
            return _BAD_CRC
        return end

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


def _next_start(buf: bytearray, start: int) -> int:
    """Where the next binary sync or ASCII '#' is, from `start` (-1: none)."""
    binary = buf.find(SYNC, start)
    text = buf.find(ASCII_SYNC, start, binary if binary >= 0 else len(buf))
    return text if text >= 0 else binary
