"""OEM4 commands in binary form (vol. 2 chapter 2) and the receiver's responses (chapter 4).

Each command is a frozen dataclass whose fields are the manual's binary fields in order;
``body()`` packs them and ``from_body()`` unpacks them (the twin uses the latter), so a
command is one declaration, not an encoder and a decoder kept in step by hand. Tables and
sections are OEM4 vol. 2's (docs/README.md#sources); what the driver relies on is written out
in docs/sensors.md#commands-and-responses and docs/sensors.md#start-up-sequence.
"""
from __future__ import annotations

import struct
from dataclasses import astuple, dataclass, fields, replace
from typing import ClassVar

from .enums import (
    ComPort,
    DgpsType,
    Dynamics,
    Handshake,
    InterfaceMode,
    MessageId,
    Parity,
    Port,
    ResponseId,
    Responses,
    SbasKeyword,
    SbasSystem,
    SbasTestMode,
    Trigger,
)
from .framing import RESPONSE_BIT, Header, encode_frame


class CommandError(Exception):
    """The receiver answered a command with something other than OK."""

    def __init__(self, command: str, response_id: int, text: str):
        self.command = command
        self.response_id = ResponseId(response_id)
        self.text = text
        super().__init__(f"{command} rejected by the receiver: {text!r} "
                         f"(response {int(response_id)} {self.response_id.name})")


class CommandTimeout(Exception):
    """No response to a command within its timeout."""


class BodyError(ValueError):
    """A command or log body has the wrong size for its message ID."""


@dataclass(frozen=True)
class Command:
    """Base of all commands: subclasses declare MESSAGE_ID, _BODY and their fields."""

    MESSAGE_ID: ClassVar[int]
    _BODY: ClassVar[struct.Struct]
    _ENUMS: ClassVar[dict] = {}

    @property
    def name(self) -> str:
        return MessageId(self.MESSAGE_ID).name

    def body(self) -> bytes:
        return self._BODY.pack(*astuple(self))

    @classmethod
    def from_body(cls, body: bytes) -> Command:
        if len(body) != cls._BODY.size:
            raise BodyError(f"{MessageId(cls.MESSAGE_ID).name} body is {len(body)} bytes, "
                            f"expected {cls._BODY.size}")
        values = cls._BODY.unpack(body)
        kwargs = {}
        for f, v in zip(fields(cls), values):
            enum = cls._ENUMS.get(f.name)
            kwargs[f.name] = enum(v) if enum else v
        return cls(**kwargs)

    def frame(self, port_address: int = Port.THISPORT, sequence: int = 0) -> bytes:
        """The complete binary message: header (time fields 0, as the manual advises),
        body and CRC."""
        header = Header(self.MESSAGE_ID, port_address=port_address, sequence=sequence)
        return encode_frame(header, self.body())


@dataclass(frozen=True)
class Log(Command):
    """LOG: ask for a log on a port with a trigger (Table 29)."""

    MESSAGE_ID = MessageId.LOG
    _BODY = struct.Struct("<LHBBLddL")
    _ENUMS = {"port": Port, "message": MessageId, "trigger": Trigger}

    port: int = Port.THISPORT
    message: int = MessageId.BESTXYZ
    message_type: int = 0           # binary, original message
    reserved: int = 0
    trigger: int = Trigger.ONTIME
    period: float = 1.0
    offset: float = 0.0
    hold: int = 0                   # 1 = survive a default UNLOGALL


@dataclass(frozen=True)
class Unlog(Command):
    """UNLOG: stop one log (Table 39)."""

    MESSAGE_ID = MessageId.UNLOG
    _BODY = struct.Struct("<LHBB")
    _ENUMS = {"port": Port, "message": MessageId}

    port: int = Port.THISPORT
    message: int = MessageId.BESTXYZ
    message_type: int = 0
    reserved: int = 0


@dataclass(frozen=True)
class Unlogall(Command):
    """UNLOGALL: stop every log on a port; held=1 also removes HOLD logs."""

    MESSAGE_ID = MessageId.UNLOGALL
    _BODY = struct.Struct("<LL")
    _ENUMS = {"port": Port}

    port: int = Port.ALL_PORTS
    held: int = 1


@dataclass(frozen=True)
class Com(Command):
    """COM: serial port configuration (§2.6.10)."""

    MESSAGE_ID = MessageId.COM
    _BODY = struct.Struct("<8L")
    _ENUMS = {"port": ComPort, "parity": Parity, "handshake": Handshake}

    port: int = ComPort.THISPORT
    baud: int = 115200
    parity: int = Parity.N
    databits: int = 8
    stopbits: int = 1
    handshake: int = Handshake.N
    echo: int = 0
    break_detection: int = 1


@dataclass(frozen=True)
class DynamicsCommand(Command):
    """DYNAMICS: tune reacquisition to the platform (Table 21)."""

    MESSAGE_ID = MessageId.DYNAMICS
    _BODY = struct.Struct("<L")
    _ENUMS = {"dynamics": Dynamics}

    dynamics: int = Dynamics.AIR


def sbas_keyword_value(keyword: SbasKeyword, enable_value: int = SbasKeyword.ENABLE) -> int:
    """The binary keyword to send for ENABLE or DISABLE to a receiver whose firmware reads
    `enable_value` as ENABLE (0 in the OEM4 2.310 manual's table, 1 in later firmware);
    DISABLE is the other value."""
    if enable_value not in (0, 1):
        raise ValueError(f"SBASCONTROL's ENABLE is 0 or 1, not {enable_value!r}")
    return enable_value if keyword == SbasKeyword.ENABLE else 1 - enable_value


@dataclass(frozen=True)
class SbasControl(Command):
    """SBASCONTROL: 16-byte body, keyword ENABLE = 0 by the OEM4 manual's table (§2.6.50;
    see `sbas_keyword_value` for a firmware that reads it the other way)."""

    MESSAGE_ID = MessageId.SBASCONTROL
    _BODY = struct.Struct("<LLLL")
    _ENUMS = {"keyword": SbasKeyword, "system": SbasSystem, "testmode": SbasTestMode}

    keyword: int = SbasKeyword.ENABLE
    system: int = SbasSystem.AUTO
    prn: int = 0                    # 0 = any, 120-138 = only this GEO
    testmode: int = SbasTestMode.NONE


@dataclass(frozen=True)
class Reset(Command):
    """RESET: hardware reset after a delay in seconds."""

    MESSAGE_ID = MessageId.RESET
    _BODY = struct.Struct("<L")

    delay: int = 0


@dataclass(frozen=True)
class SaveConfig(Command):
    """SAVECONFIG: store the present configuration in NVM (empty body)."""

    MESSAGE_ID = MessageId.SAVECONFIG
    _BODY = struct.Struct("<")


@dataclass(frozen=True)
class InterfaceModeCommand(Command):
    """INTERFACEMODE: what a port accepts and generates (§2.6.28, Table 28). A port whose
    rxtype is not NOVATEL takes no more commands (on the port the commands go through it
    must be the last one); a break puts it back to NOVATEL NOVATEL."""

    MESSAGE_ID = MessageId.INTERFACEMODE
    _BODY = struct.Struct("<LLLL")
    _ENUMS = {"port": ComPort, "rxtype": InterfaceMode, "txtype": InterfaceMode, "responses": Responses}

    port: int = ComPort.THISPORT
    rxtype: int = InterfaceMode.NOVATEL
    txtype: int = InterfaceMode.NOVATEL
    responses: int = Responses.ON


@dataclass(frozen=True)
class DgpsTimeout(Command):
    """DGPSTIMEOUT: the oldest pseudorange correction used, 2-1000 s (§2.6.16); RTK
    corrections time out after 60 s whatever this says."""

    MESSAGE_ID = MessageId.DGPSTIMEOUT
    _BODY = struct.Struct("<L")

    delay: int = 300


#: The ID field of PSRDIFFSOURCE and RTKSOURCE: Char[5] plus 3 bytes of padding (§2.6.40).
SOURCE_ID_BYTES = 8


@dataclass(frozen=True)
class _SourceCommand(Command):
    """A correction source: type (Table 31) and base station ID ("ANY", or a number or name
    in the type's range, see `source_id_error`)."""

    _BODY = struct.Struct(f"<L{SOURCE_ID_BYTES}s")
    _ENUMS = {"type": DgpsType}

    type: int = DgpsType.AUTO
    id: str = "ANY"

    def body(self) -> bytes:
        return self._BODY.pack(self.type, self.id.encode("ascii", "replace")[:5])

    @classmethod
    def from_body(cls, body: bytes) -> Command:
        if len(body) != cls._BODY.size:
            raise BodyError(f"{MessageId(cls.MESSAGE_ID).name} body is {len(body)} bytes, "
                            f"expected {cls._BODY.size}")
        kind, raw = cls._BODY.unpack(body)
        return cls(DgpsType(kind), raw[:5].split(b"\0", 1)[0].decode("ascii", "replace"))


@dataclass(frozen=True)
class PsrDiffSource(_SourceCommand):
    """PSRDIFFSOURCE: which base's pseudorange corrections to use (§2.6.40). Every type
    falls back to SBAS when SBAS is enabled; CMR is not a pseudorange source."""

    MESSAGE_ID = MessageId.PSRDIFFSOURCE


@dataclass(frozen=True)
class RtkSource(_SourceCommand):
    """RTKSOURCE: which base's RTK corrections to use (§2.6.47)."""

    MESSAGE_ID = MessageId.RTKSOURCE


#: The base station IDs each type takes (Table 31), besides "ANY".
_NUMERIC_ID_MAX = {DgpsType.RTCM: 1023, DgpsType.CMR: 31, DgpsType.RTCMV3: 4095}


def source_id_error(kind: DgpsType | int, source_id: str) -> str:
    """Why `source_id` is not a base station ID of `kind` by Table 31 ("" when it is): RTCM
    0-1023, RTCMV3 0-4095, CMR 0-31, RTCA four letters or digits; "ANY" for every type."""
    if source_id == "ANY":
        return ""
    kind = DgpsType(kind)
    if kind in _NUMERIC_ID_MAX:
        top = _NUMERIC_ID_MAX[kind]
        if source_id.isdigit() and int(source_id) <= top:
            return ""
        return f"{kind.name} base ID is 0-{top} or ANY, not {source_id!r}"
    if kind == DgpsType.RTCA:
        if len(source_id) == 4 and source_id.isascii() and source_id.isalnum():
            return ""
        return f"RTCA base ID is four letters or digits or ANY, not {source_id!r}"
    return ""                       # the other types ignore the ID


COMMANDS: dict[int, type[Command]] = {
    c.MESSAGE_ID: c for c in (Log, Unlog, Unlogall, Com, DynamicsCommand, SbasControl,
                              Reset, SaveConfig, InterfaceModeCommand, DgpsTimeout,
                              PsrDiffSource, RtkSource)
}


def decode_command(header: Header, body: bytes) -> Command:
    """The command a binary frame carries; KeyError for an unknown ID, BodyError for a
    body of the wrong size."""
    return COMMANDS[header.message_id].from_body(body)


@dataclass(frozen=True)
class Response:
    """A binary response: ENUM response ID + the receiver's ASCII text (§1.2)."""

    response_id: int
    text: str

    _ID = struct.Struct("<L")

    @property
    def ok(self) -> bool:
        return self.response_id == ResponseId.OK

    def body(self) -> bytes:
        return self._ID.pack(self.response_id) + self.text.encode("ascii", "replace")

    @classmethod
    def from_body(cls, body: bytes) -> Response:
        if len(body) < 4:
            raise BodyError(f"response body is {len(body)} bytes, expected at least 4")
        text = body[4:].split(b"\0", 1)[0].decode("ascii", "replace").strip()
        return cls(ResponseId(cls._ID.unpack_from(body)[0]), text)

    def frame(self, header: Header) -> bytes:
        """Encode as a response to a command with the given header fields."""
        return encode_frame(replace(header, message_type=header.message_type | RESPONSE_BIT),
                            self.body())
