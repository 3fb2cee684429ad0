"""What a NovAtel OEM4 reads of RTCM 3 on a port in RTCMV3 mode (INTERFACEMODE, vol. 2
§2.6.28 Table 28): whole frames (preamble 0xD3, 10-bit length, CRC-24Q: viena.common.rtcm3)
parsed with pyrtcm, and of them only the messages its firmware decodes: 1001-1004 (GPS RTK
observables) and 1005/1006 (the base's antenna reference point), the RTCMV3 set of the
2.310 manual (vol. 2 §3.4.73). Anything else (MSM, 1033, GLONASS) is skipped, counted by
message number; bytes that are not a frame, or a frame whose CRC fails, are skipped too; a
frame whose CRC checks but whose message pyrtcm cannot parse (a broken base: a 1005 cut
short) is skipped and counted as `malformed`, never raised into the twin's thread.
"""
from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass

from pyrtcm import RTCMMessageError, RTCMParseError, RTCMReader, RTCMTypeError

from viena.common.rtcm3 import Frame, Rtcm3Framer
from viena.services.gnss.driver.novatel.corrections import RTCM3_DECODED as DECODED

#: what pyrtcm raises on a frame it cannot parse (and the bit reading under it; a field
#: missing from what it parsed)
PARSE_ERRORS = (RTCMParseError, RTCMTypeError, RTCMMessageError, ValueError, IndexError, AttributeError)
log = logging.getLogger(__name__)

#: Observables with L2 (RT-2 can fix on these; 1001/1002 are L1 only).
L1L2_OBSERVABLES = (1003, 1004)


@dataclass(frozen=True)
class BasePosition:
    """1005/1006: a base station's antenna reference point, ECEF metres."""

    base_id: str
    ecef_m: tuple[float, float, float]


@dataclass(frozen=True)
class Observables:
    """1001-1004: a base's GPS observables of one epoch (GPS time of week, ms)."""

    number: int
    base_id: str
    tow_ms: int
    satellites: int

    @property
    def l2(self) -> bool:
        return self.number in L1L2_OBSERVABLES


class RtcmInput:
    """RTCM 3 bytes in, the messages the receiver uses out; counts what it skipped."""

    def __init__(self) -> None:
        self._framer = Rtcm3Framer()
        self.decoded: Counter[int] = Counter()    # by message number
        self.ignored: Counter[int] = Counter()    # frames it cannot use, by message number
        self.malformed: Counter[int] = Counter()  # CRC-checked frames pyrtcm cannot parse, by number

    @property
    def frames(self) -> int:
        """Frames whose CRC checked."""
        return self._framer.frames

    @property
    def crc_errors(self) -> int:
        return self._framer.crc_errors

    def clear(self) -> None:
        self._framer.reset()

    def feed(self, data: bytes) -> list[BasePosition | Observables]:
        out = []
        for frame in self._framer.feed(data):
            message = self._message(frame)
            if message is not None:
                out.append(message)
        return out

    def _message(self, frame: Frame) -> BasePosition | Observables | None:
        number = frame.type
        if number not in DECODED:
            self.ignored[number] += 1
            return None
        try:
            msg = RTCMReader.parse(frame.data, validate=0)
            base_id = str(int(msg.DF003))
            if number in (1005, 1006):
                message: BasePosition | Observables = BasePosition(
                    base_id, (float(msg.DF025), float(msg.DF026), float(msg.DF027)))
            else:
                message = Observables(number, base_id, int(msg.DF004), int(msg.DF006))
        except PARSE_ERRORS as exc:
            self.malformed[number] += 1
            log.debug("RTCM %d frame not parsed: %s", number, exc)
            return None
        self.decoded[number] += 1
        return message
