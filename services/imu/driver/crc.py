"""CRC-8/MAXIM (Dallas/Maxim iButton): poly 0x31 reflected (0x8C), init 0, no final xor.

The car's Razor firmware protects each frame with it (FastCRC8::maxim). No standard-library
module computes an 8-bit CRC, so the 256-entry table is built here from the polynomial;
check("123456789") == 0xA1 is the catalogue's test vector.
"""
from __future__ import annotations


def _table(poly_reflected: int = 0x8C) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ poly_reflected if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


TABLE = _table()


def crc8_maxim(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC of `data`, continuing from `crc` (0 for a fresh computation)."""
    table = TABLE
    for b in data:
        crc = table[crc ^ b]
    return crc
