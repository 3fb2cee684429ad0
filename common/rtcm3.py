"""RTCM 3 frames in a byte stream: whole, CRC-24Q checked, what lies between them counted.

A frame is 0xD3, 6 reserved zero bits, a 10-bit payload length, the payload (its first 12
bits the message number, DF002) and a CRC-24Q over all that (pyrtcm's `calc_crc24q`).
pyrtcm's message definitions say which messages name their reference station (DF003, the
12 bits after the number): 1001-1013, 1029-1035, the MSMs, 1230.

Both ends of the corrections chain cut the stream here: the NTRIP client (it publishes
whole checked frames, never garbage) and the GNSS service (it drops whole frames a receiver
cannot decode or its serial line cannot carry, never part of one).

Why not pyrtcm's RTCMReader or pygnssutils' GNSSReader: they read one message per call from
a blocking stream, so they cannot say "these are the whole frames this read brought"; they
drop the bytes they skip without counting them; GNSSReader looks for every protocol's header
even when told to keep RTCM only (an ``s`` or ``$`` among garbage bytes swallows the frames
behind it), and neither goes back to the byte after a false 0xD3 whose CRC fails. This one
resynchronises there, counts what it skips, and parses nothing it does not need.
"""
from __future__ import annotations

from typing import NamedTuple

from pyrtcm.rtcmhelpers import calc_crc24q
from pyrtcm.rtcmtypes_get import RTCM_PAYLOADS_GET
from pyrtcm.rtcmtypes_get_msm import RTCM_PAYLOADS_GET_MSM

PREAMBLE = 0xD3
#: header (preamble, reserved bits, length) and CRC around the payload
OVERHEAD = 6
MAX_PAYLOAD = 1023
MAX_FRAME = MAX_PAYLOAD + OVERHEAD


def _station_id_types() -> frozenset[int]:
    """The messages whose payload starts with DF002 (message number) then DF003 (reference
    station id), as pyrtcm defines them."""
    found = set()
    for table in (RTCM_PAYLOADS_GET, RTCM_PAYLOADS_GET_MSM):
        for number, fields in table.items():
            if list(fields)[:2] == ["DF002", "DF003"] and number.isdigit():
                found.add(int(number))
    return frozenset(found)


#: messages that name their reference station (DF003, 12 bits after the message number)
STATION_ID_TYPES = _station_id_types()


class Frame(NamedTuple):
    """One whole checked frame (header, payload, CRC) and its message number."""

    data: bytes
    type: int

    @property
    def station_id(self) -> int | None:
        """The reference station the frame names (DF003), if its message names one."""
        if self.type not in STATION_ID_TYPES or len(self.data) < OVERHEAD + 3:
            return None
        return ((self.data[4] & 0x0F) << 8) | self.data[5]


def message_number(frame: bytes) -> int:
    """The message number of a whole frame (0 for a payload shorter than its number)."""
    if len(frame) < OVERHEAD + 2:
        return 0
    return (frame[3] << 4) | (frame[4] >> 4)


class Rtcm3Framer:
    """Feed it bytes cut anywhere, get the whole checked frames they complete; a partial
    frame waits for the next bytes. Counts since start: `frames`, `garbage_bytes` (not part
    of any checked frame), `crc_errors` (candidate frames whose CRC failed)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.frames = 0
        self.garbage_bytes = 0
        self.crc_errors = 0

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        n = len(buf)
        out: list[Frame] = []
        skipped = 0
        i = 0
        while i < n:
            j = buf.find(PREAMBLE, i)
            if j < 0:
                skipped += n - i
                i = n
                break
            skipped += j - i
            i = j
            if n - i < 3:
                break                                   # wait for the header
            length = ((buf[i + 1] & 0x03) << 8) | buf[i + 2]
            if buf[i + 1] & 0xFC or length < 2:         # reserved bits set, or no message number
                skipped += 1
                i += 1
                continue
            end = i + length + OVERHEAD
            if end > n:
                break                                   # wait for the rest of the frame
            frame = bytes(buf[i:end])
            if calc_crc24q(frame):
                self.crc_errors += 1
                skipped += 1                            # a false start: resync on the next byte
                i += 1
                continue
            out.append(Frame(frame, (frame[3] << 4) | (frame[4] >> 4)))
            i = end
        del buf[:i]
        self.frames += len(out)
        self.garbage_bytes += skipped
        return out

    def reset(self) -> int:
        """A new stream begins: the partial frame left (its bytes, counted as garbage) goes."""
        left = len(self._buf)
        self._buf.clear()
        self.garbage_bytes += left
        return left

    @property
    def pending(self) -> int:
        """Bytes held back, waiting for the rest of a frame."""
        return len(self._buf)


def family(message: int) -> str:
    """What an RTCM 3 message is, in a word or two ('MSM', 'GLONASS observables' ...): for
    the line that says why a receiver is not given it."""
    if 1071 <= message <= 1137 and 1 <= message % 10 <= 7:
        return "MSM"
    if 1001 <= message <= 1004:
        return "GPS observables"
    if message in (1005, 1006, 1032):
        return "base position"
    if message in (1007, 1008, 1033):
        return "antenna descriptors"
    if 1009 <= message <= 1012:
        return "GLONASS observables"
    if message in (1019, 1020, 1041, 1042, 1043, 1044, 1045, 1046):
        return "ephemerides"
    if message == 1230:
        return "GLONASS biases"
    if 1013 <= message <= 1039 or 1057 <= message <= 1068 or 1240 <= message <= 1270:
        return "network or state-space"
    if 4001 <= message <= 4095:
        return "proprietary"
    return "other"
