"""A PDO's mapping worked out once, so the EPOS twin packs and unpacks it with one struct."""
from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import INTEGER_TYPES


class PdoLayout:
    """A PDO of whole integers at whole bytes, each as long as its object (what the EPOS
    maps): one struct packs or unpacks it all, instead of canopen's per-variable bit
    slicing and object dictionary lookups. Other mappings go through canopen."""

    def __init__(self, variables: list, fmt: struct.Struct, readers: list):
        self.variables, self.struct, self.readers = variables, fmt, readers

    @classmethod
    def of(cls, pdo, readers: dict[int, Callable[[int], int | None]]) -> PdoLayout | None:
        variables, fmt, bits, served = [], "<", 0, []
        for var in pdo:
            if not var.length:
                continue
            od = var.od
            code = ODVariable.STRUCT_TYPES.get(od.data_type)
            if type(code) is not struct.Struct or od.data_type not in INTEGER_TYPES or var.offset != bits \
                    or var.length != len(od) or od.min is not None or od.max is not None:
                return None
            variables.append(var)
            fmt += code.format.lstrip("<")
            bits += var.length
            reader = readers.get(var.index)
            served.append(None if reader is None else (reader, var.subindex))
        if not variables:
            return None
        return cls(variables, struct.Struct(fmt), served if None not in served else [])

    def unpack(self, data: bytes) -> list[tuple[Any, int, bytes]]:
        """(variable, value, its bytes) for each mapped variable of a received PDO."""
        values = self.struct.unpack_from(data)
        return [(var, value, bytes(data[var.offset // 8:(var.offset + var.length) // 8]))
                for var, value in zip(self.variables, values)]

    def pack(self) -> bytes | None:
        """The bytes of a PDO whose objects the twin computes (its read callback), or None
        (objects from the data store, or a value that does not fit: canopen says why)."""
        if not self.readers:
            return None
        try:
            return self.struct.pack(*[read(sub) for read, sub in self.readers])
        except struct.error:
            return None

