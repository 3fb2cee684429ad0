"""A binary record defined once, as pyubx2 defines UBX messages: each field of the record's
dataclass names its wire type (a struct code), its count (3 for a vector) and its table (an
enum) or its text; one generic read (`from_body`) and one generic build (`body`, `pack`) use
them through one struct compiled per record, so a log's layout is never written twice.

    class BestVel(BinaryRecord):
        MESSAGE_ID = MessageId.BESTVEL
        vel_status: SolutionStatus = wire("L", enum=SolutionStatus)
        latency_s: float = wire("f")
        ...
"""
from __future__ import annotations

import dataclasses
import operator
import struct
from collections.abc import Callable, Sequence
from dataclasses import MISSING, dataclass, fields
from typing import Any, ClassVar, Self, dataclass_transform

from .commands import BodyError
from .enums import MessageId, OpenEnum

Reader = Callable[[tuple], Any]


@dataclass(frozen=True)
class Wire:
    """How one field is carried: `count` values of struct `code` ("L", "B", "f", "d", or
    "4s": n bytes), read through `enum`'s table, or as `text` (NUL-padded ASCII)."""

    code: str
    count: int = 1
    enum: type[OpenEnum] | None = None
    text: bool = False

    @property
    def format(self) -> str:
        return self.code if self.count == 1 else f"{self.count}{self.code}"


def wire(code: str, *, count: int = 1, enum: type[OpenEnum] | None = None, text: bool = False,
         default: Any = MISSING) -> Any:
    """A record's field and how it is carried (a dataclass field with its Wire)."""
    return dataclasses.field(default=default, metadata={"wire": Wire(code, count, enum, text)})


def _text(raw: bytes) -> str:
    """A Char[n] field: the text up to its first NUL."""
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def _reader(w: Wire, i: int) -> Reader:
    """What makes one field's value of the unpacked tuple (plain values by itemgetter)."""
    if w.count > 1:
        return operator.itemgetter(slice(i, i + w.count))
    if w.enum is not None:
        of = w.enum.of
        return lambda values: of(values[i])
    if w.text:
        return lambda values: _text(values[i])
    return operator.itemgetter(i)


class BodyCodec:
    """A record's fields to and from its body, through one precompiled struct."""

    def __init__(self, record: type, name: str):
        self.name = name
        specs = [(f, f.metadata["wire"]) for f in fields(record)]
        self.struct = struct.Struct("<" + "".join(w.format for _, w in specs))
        self.size = self.struct.size
        self.wires = tuple(w for _, w in specs)
        self.names = tuple(f.name for f, _ in specs)
        self.defaults = tuple(f.default for f, _ in specs)
        readers, i = [], 0
        for _, w in specs:
            readers.append(_reader(w, i))
            i += w.count
        self.readers = tuple(readers)

    def unpack_from(self, body: bytes, offset: int = 0) -> list:
        """The fields' values at `offset`, in order."""
        values = self.struct.unpack_from(body, offset)
        return [read(values) for read in self.readers]

    def unpack(self, body: bytes) -> list:
        if len(body) != self.size:
            raise BodyError(f"{self.name} body is {len(body)} bytes, expected {self.size}")
        return self.unpack_from(body)

    def pack(self, values: Sequence) -> bytes:
        """The body of these fields' values, in order (missing trailing ones their defaults)."""
        if len(values) < len(self.wires):
            values = (*values, *self.defaults[len(values):])
        flat: list = []
        for w, value in zip(self.wires, values):
            if w.count > 1:
                flat.extend(value)
            elif w.text:
                flat.append(value.encode("ascii", "replace"))   # struct pads with NULs, or cuts
            else:
                flat.append(value)
        return self.struct.pack(*flat)


@dataclass_transform(frozen_default=True, field_specifiers=(wire,))
class BinaryRecord:
    """Base of the records defined by their fields' wires: each subclass is a frozen
    dataclass with its CODEC; a log also names its MESSAGE_ID."""

    MESSAGE_ID: ClassVar[int]
    CODEC: ClassVar[BodyCodec]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        dataclass(frozen=True)(cls)
        message_id = cls.__dict__.get("MESSAGE_ID")
        cls.CODEC = BodyCodec(cls, cls.__name__ if message_id is None else MessageId(message_id).name)

    def body(self) -> bytes:
        return self.CODEC.pack([getattr(self, name) for name in self.CODEC.names])

    @classmethod
    def pack(cls, *values: Any) -> bytes:
        """The body of a record of these fields (in order) without making one: the twin
        writes one every epoch."""
        return cls.CODEC.pack(values)

    @classmethod
    def from_body(cls, body: bytes) -> Self:
        """The record a body carries; BodyError if its size is not the record's."""
        return cls(*cls.CODEC.unpack(body))

    @classmethod
    def unpack_from(cls, body: bytes, offset: int) -> Self:
        return cls(*cls.CODEC.unpack_from(body, offset))
