"""EPOS emergency messages (EMCY) by name: firmware specification §12.2, table 37.

An EMCY frame is `<error code u16><error register u8><5 bytes>` on COB-ID 0x80 + node.
Code 0x0000 says every error was cleared (EPOS sends it after a successful fault reset).
Written out in docs/steering.md#emcy; the specification is listed in docs/README.md#sources.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

#: error code -> name, as the EPOS firmware specification lists them
EPOS_ERRORS: dict[int, str] = {
    0x0000: "No Error",
    0x1000: "Generic Error",
    0x2310: "Over Current Error",
    0x3210: "Over Voltage Error",
    0x3220: "Under Voltage",
    0x4210: "Over Temperature",
    0x5113: "Supply Voltage (+5V) too low",
    0x6100: "Internal Software Error",
    0x6320: "Software Parameter Error",
    0x7320: "Sensor Position Error",
    0x8110: "CAN Overrun Error (Objects lost)",
    0x8111: "CAN Overrun Error",
    0x8120: "CAN Passive Mode Error",
    0x8130: "CAN Life Guard Error",
    0x8150: "CAN Transmit COB-ID collision",
    0x81FD: "CAN Bus Off",
    0x81FE: "CAN Rx Queue Overrun",
    0x81FF: "CAN Tx Queue Overrun",
    0x8210: "CAN PDO length Error",
    0x8611: "Following Error",
    0xFF01: "Hall Sensor Error",
    0xFF02: "Index Processing Error",
    0xFF03: "Encoder Resolution Error",
    0xFF04: "Hallsensor not found Error",
    0xFF06: "Negative Limit Error",
    0xFF07: "Positive Limit Error",
    0xFF08: "Hall Angle detection Error",
    0xFF09: "Software Position Limit Error",
    0xFF0A: "Position Sensor Breach",
    0xFF0B: "System Overloaded",
}

#: the error register bit each code sets (table 37), used by the twin
ERROR_REGISTER: dict[int, int] = {
    0x1000: 0x01, 0x2310: 0x02, 0x3210: 0x04, 0x3220: 0x04, 0x5113: 0x04, 0x4210: 0x08,
    0x8110: 0x10, 0x8111: 0x10, 0x8120: 0x10, 0x8130: 0x10, 0x8150: 0x10, 0x81FD: 0x10,
    0x81FE: 0x10, 0x81FF: 0x10, 0x8210: 0x10,
    0x6100: 0x20, 0x6320: 0x20, 0x7320: 0x20, 0x8611: 0x20, 0xFF0B: 0x20,
    0xFF01: 0x80, 0xFF02: 0x80, 0xFF03: 0x80, 0xFF04: 0x80, 0xFF06: 0x80, 0xFF07: 0x80,
    0xFF08: 0x80, 0xFF09: 0x80, 0xFF0A: 0x80,
}

FOLLOWING_ERROR = 0x8611
LIFE_GUARD_ERROR = 0x8130
SOFTWARE_POSITION_LIMIT_ERROR = 0xFF09

_FRAME = struct.Struct("<HB5s")


def emcy_name(code: int) -> str:
    """The EPOS name of an error code, or its CiA 301 class for codes the EPOS never sends."""
    if code in EPOS_ERRORS:
        return EPOS_ERRORS[code]
    classes = {0x1: "Generic", 0x2: "Current", 0x3: "Voltage", 0x4: "Temperature",
               0x5: "Device Hardware", 0x6: "Device Software", 0x7: "Additional Modules",
               0x8: "Monitoring", 0x9: "External", 0xF: "Device Specific"}
    return f"unknown error ({classes.get(code >> 12, 'unknown class')})"


@dataclass(frozen=True)
class Emcy:
    """One received emergency message."""
    code: int
    register: int
    data: bytes = b""

    @property
    def name(self) -> str:
        return emcy_name(self.code)

    @property
    def is_reset(self) -> bool:
        return self.code == 0x0000

    def __str__(self) -> str:
        return f"EMCY 0x{self.code:04X} {self.name}"

    @classmethod
    def decode(cls, data: bytes) -> Emcy:
        """Parse an EMCY payload; short frames are padded (some stacks send fewer bytes)."""
        code, register, extra = _FRAME.unpack(bytes(data[:8]).ljust(8, b"\0"))
        return cls(code, register, extra)

    def encode(self) -> bytes:
        return _FRAME.pack(self.code, self.register, self.data.ljust(5, b"\0")[:5])
