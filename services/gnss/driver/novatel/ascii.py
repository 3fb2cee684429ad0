"""OEM4 ASCII messages (vol. 2 §1.1.1, table 3): what the receiver says with names, not numbers.
Written out in docs/sensors.md#novatel-oem4-binary-framing and docs/sensors.md#sbas.

    #NAME,port,sequence,%idle,time status,week,seconds,rx status,reserved,sw version;data,...*crc CR LF

The CRC-32 (the binary one, framing.crc32) covers everything between '#' and the last '*',
written as 8 hex digits. viena asks for one ASCII log: RXCONFIG (§3.4.84), the receiver's
own list of its settings, one log per command, each embedding that command as an ASCII
message whose CRC is inverted (bitwise) so that the receiver does not take it for a command:

    #RXCONFIGA,COM1,70,72.0,UNKNOWN,0,1.656,00000000,f702,1522;#ADJUST1PPSA,COM1,70,72.0,
    UNKNOWN,0,1.656,00000000,f702,1522;OFF,ONCE,0*ad21fe17*7d34bfd1        (one line)

In ASCII an enumeration is written as its label ("In binary, the enumerated value is output.
In ASCII or Abbreviated ASCII, the enumeration label is output", §1.2), so RXCONFIGA says
ENABLE or DISABLE in the receiver's own words, whatever number a binary command carried.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from .framing import AsciiFrame, crc32

_CRC = re.compile(r"\*([0-9a-fA-F]{8})$")
#: header fields after the name: port, sequence, idle, time status, week, seconds,
#: receiver status, reserved, software version
HEADER_FIELDS = 9


class AsciiError(ValueError):
    """Not a well-formed ASCII message (its CRC included)."""


@dataclass(frozen=True)
class AsciiMessage:
    """One ASCII message whose CRC checked out."""

    name: str                       # as sent: RXCONFIGA, SBASCONTROLA, ...
    header: tuple[str, ...]         # the header's fields after the name (HEADER_FIELDS of them)
    data: str                       # between ';' and the CRC's '*'
    t_host_ns: int = 0              # host clock when its last byte was read

    @property
    def message(self) -> str:
        """The message's name without the format letter: RXCONFIGA -> RXCONFIG."""
        return self.name[:-1] if self.name.endswith("A") else self.name

    @property
    def port(self) -> str:
        return self.header[0]

    @property
    def sequence(self) -> int:
        """Counts down to 0 over a set of related logs (RXCONFIG's one log per setting)."""
        return int(self.header[1])

    def fields(self) -> tuple[str, ...]:
        return split_fields(self.data)


def split_fields(data: str) -> tuple[str, ...]:
    """Comma-separated fields; a string in double quotes is one field (§1.1.1 rule 5)."""
    fields: list[str] = []
    field: list[str] = []
    quoted = False
    for c in data:
        if c == '"':
            quoted = not quoted
        elif c == "," and not quoted:
            fields.append("".join(field))
            field = []
            continue
        field.append(c)
    fields.append("".join(field))
    return tuple(fields)


def message_of(frame: AsciiFrame) -> AsciiMessage:
    """The message in a frame the decoder found (its CRC already checked)."""
    return _split(frame.text, frame.t_host_ns)


def parse_ascii(text: str, t_host_ns: int = 0, *, inverted_crc: bool = False) -> AsciiMessage:
    """An ASCII message from its text without the leading '#' and the line end; AsciiError
    if it is malformed or its CRC (inverted, for an embedded one) does not check."""
    m = _CRC.search(text)
    if m is None:
        raise AsciiError(f"no *crc at the end of {text[:40]!r}")
    body = text[:m.start()]
    crc = crc32(body.encode("ascii"))
    if inverted_crc:
        crc ^= 0xFFFFFFFF
    if crc != int(m.group(1), 16):
        raise AsciiError(f"bad CRC in {text[:40]!r}")
    return _split(body, t_host_ns)


def _split(body: str, t_host_ns: int) -> AsciiMessage:
    head, sep, data = body.partition(";")
    fields = head.split(",")
    if not sep or len(fields) != 1 + HEADER_FIELDS or not fields[0]:
        raise AsciiError(f"not an ASCII header: {head[:60]!r}")
    return AsciiMessage(fields[0], tuple(fields[1:]), data, t_host_ns)


def encode_ascii(name: str, data: str, *, port: str = "COM1", sequence: int = 0,
                 idle_percent: float = 80.0, time_status: str = "FINESTEERING", week: int = 0,
                 seconds: float = 0.0, receiver_status: int = 0, sw_version: int = 1522,
                 inverted_crc: bool = False) -> str:
    """The text of an ASCII message, from its name to its CRC (no '#', no line end)."""
    body = (f"{name},{port},{sequence},{idle_percent:.1f},{time_status},{week},{seconds:.3f},"
            f"{receiver_status:08x},0000,{sw_version};{data}")
    crc = crc32(body.encode("ascii"))
    if inverted_crc:
        crc ^= 0xFFFFFFFF
    return f"{body}*{crc:08x}"


def ascii_line(text: str) -> bytes:
    """A message's text as it goes on the line."""
    return b"#" + text.encode("ascii") + b"\r\n"


@dataclass(frozen=True)
class ConfigEntry:
    """One RXCONFIG log: a command as the receiver holds it, its fields by label."""

    command: str                    # SBASCONTROL, COM, LOG, ...
    fields: tuple[str, ...]
    sequence: int                   # 0 for the last log of the set
    t_host_ns: int = 0


def config_entry(message: AsciiMessage) -> ConfigEntry:
    """The command an RXCONFIGA log embeds (its inverted CRC checked); AsciiError if the
    message is not one."""
    if message.message != "RXCONFIG" or not message.data.startswith("#"):
        raise AsciiError(f"{message.name} does not embed a command")
    inner = parse_ascii(message.data[1:], message.t_host_ns, inverted_crc=True)
    return ConfigEntry(inner.message, inner.fields(), message.sequence, message.t_host_ns)


def rxconfig_text(command: str, data: str, sequence: int, **header) -> str:
    """An RXCONFIGA log embedding `command` with `data` (the twin's side of config_entry)."""
    inner = encode_ascii(command + "A", data, sequence=sequence, inverted_crc=True, **header)
    return encode_ascii("RXCONFIGA", "#" + inner, sequence=sequence, **header)
