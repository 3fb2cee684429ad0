"""A NovAtel receiver that takes corrections, for the driver's and the service's tests: the
NovAtel twin, plus VERSION, INTERFACEMODE, DGPSTIMEOUT, PSRDIFFSOURCE and RTKSOURCE answered
the way the manual says (OEM4 vol. 2 §2.6.16, 2.6.28, 2.6.40, 2.6.47, 3.4.94), and after an
INTERFACEMODE of this port whose rxtype is not NOVATEL, every byte kept as corrections (no
commands any more) until the next connection (the driver's break). It checks the driver's
bytes; the twin's own solution types under corrections are the twin's tests."""
from __future__ import annotations

from pyrtcm.rtcmhelpers import calc_crc24q

from viena.common.twin.serial_port import TwinWrapper
from viena.services.gnss.driver.novatel import (
    COMMANDS,
    AsciiFrame,
    Component,
    ComponentType,
    ComPort,
    FrameDecoder,
    Header,
    InterfaceMode,
    Log,
    MessageId,
    Response,
    ResponseId,
    TimeStatus,
    Version,
    encode_log,
)
from viena.services.gnss.driver.novatel.enums import RESPONSE_TEXT

CORRECTIONS_COMMANDS = (MessageId.INTERFACEMODE, MessageId.DGPSTIMEOUT, MessageId.PSRDIFFSOURCE,
                        MessageId.RTKSOURCE)


def rtcm3(number: int, size: int = 20, fill: int = 0x55) -> bytes:
    """An RTCM 3 frame of message `number` with a `size`-byte message (its number, then filler)."""
    body = bytes([number >> 4, (number & 0xF) << 4]) + bytes([fill]) * (size - 2)
    head = bytes([0xD3, (size >> 8) & 0x03, size & 0xFF])
    return head + body + calc_crc24q(head + body).to_bytes(3, "big")


class CorrectionsReceiver(TwinWrapper):
    """The twin `inner` with the corrections commands answered here (see the module)."""

    def __init__(self, inner, model: str | None = "RT2WA", firmware: str = "2.310",
                 refuse: dict | None = None, silent: tuple = ()):
        super().__init__(inner)
        self.clock = inner.clock
        self.model, self.firmware = model, firmware
        self.refuse = refuse or {}                 # MessageId -> ResponseId to answer with
        self.silent = silent                       # MessageIds done but not answered (switch first)
        self.commands: list = []                   # every command in order, decoded
        self.rxtype = InterfaceMode.NOVATEL        # this port's
        self.modes: dict = {}                      # INTERFACEMODE of the other ports
        self.corrections = bytearray()             # what came after this port switched
        self.connections = 0
        self._decoder = FrameDecoder()
        self._out = bytearray()

    @property
    def names(self) -> list[str]:
        """The commands as the manual writes them: LOG's with the log's name."""
        return [f"LOG {MessageId(c.message).name}" if isinstance(c, Log) else c.name for c in self.commands]

    def on_connect(self, now_s: float) -> None:
        self.rxtype = InterfaceMode.NOVATEL        # the driver's break
        self.connections += 1
        self._decoder.reset()
        self._out.clear()
        super().on_connect(now_s)

    def feed(self, data: bytes, now_s: float) -> None:
        if self.rxtype != InterfaceMode.NOVATEL:
            self.corrections += data
            return
        for frame in self._decoder.feed(data):
            if isinstance(frame, AsciiFrame) or frame.header.is_response:
                continue
            cls = COMMANDS.get(frame.header.message_id)
            command = cls.from_body(frame.body) if cls is not None else None
            self.commands.append(command)
            if isinstance(command, Log) and command.message == MessageId.VERSION:
                self._version(frame.header)
            elif frame.header.message_id in CORRECTIONS_COMMANDS:
                self._answer(frame.header, command)
            else:
                self.inner.feed(frame.raw, now_s)

    def poll(self, now_s: float) -> bytes:
        out = self.inner.poll(now_s) + bytes(self._out)
        self._out.clear()
        return out

    def next_due(self, now_s: float) -> float:
        return now_s if self._out else self.inner.next_due(now_s)

    def _respond(self, header: Header, response_id: ResponseId = ResponseId.OK) -> None:
        self._out += Response(response_id, RESPONSE_TEXT[response_id].format(2)).frame(header)

    def _version(self, header: Header) -> None:
        if self.model is None:
            self._respond(header, ResponseId.LOG_DOES_NOT_EXIST)
            return
        self._respond(header)
        card = Component(ComponentType.GPSCARD, self.model, "SVA03130089", "OEM4g2-2.00-X2T", self.firmware,
                         "2.000", "2004/Feb/10", "09:53:05")
        self._out += encode_log(Header(0, week=1263, milliseconds=311409177, time_status=TimeStatus.FINESTEERING),
                                Version((card,)))

    def _answer(self, header: Header, command) -> None:
        refused = self.refuse.get(MessageId(header.message_id))
        if refused is not None:
            self._respond(header, refused)
            return
        if MessageId(header.message_id) not in self.silent:
            self._respond(header)
        if header.message_id == MessageId.INTERFACEMODE:
            if command.port == ComPort.THISPORT:
                self.rxtype = InterfaceMode(command.rxtype)
            else:
                self.modes[ComPort(command.port).name] = command
