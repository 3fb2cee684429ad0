"""Payloads typed by people: JSON text from the `zenoh` CLI, or msgpack from programs.

The `zenoh` CLI sends no encoding with `put`/`get`, so the bytes themselves decide:
a msgpack map starts with 0x80-0x8f, 0xde or 0xdf, while JSON text starts with `{`.
A reply goes back in the encoding the question came in.

Whatever arrives is bounded before it is parsed: a command is small (`MAX_COMMAND_BYTES`)
and shallow (`MAX_DEPTH` levels of maps and lists), so a 64 MB or 1000-deep payload costs
a length check and a scan, never the memory or the recursion it asks for.
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import Any

import msgpack

from viena.common.errors import PayloadError
from viena.common.schema import MSGPACK, SampleError, unpack

JSON = "application/json"
#: a command is a small map: a few fields, a lease, an angle
MAX_COMMAND_BYTES = 4096
MAX_DEPTH = 8


def is_json_text(data: bytes, encoding: str | None = None) -> bool:
    if encoding:
        if encoding.startswith(MSGPACK):
            return False
        if encoding.startswith(("application/json", "text/")):
            return True
    head = bytes(data[:64]).lstrip()
    return head[:1] in (b"{", b"[")


def parse_payload(data: bytes | bytearray | memoryview, encoding: str | None = None, *,
                  max_bytes: int = MAX_COMMAND_BYTES, max_depth: int = MAX_DEPTH) -> dict:
    """A map from JSON text or msgpack; PayloadError saying what is wrong otherwise."""
    if len(data) > max_bytes:
        raise PayloadError(f"payload of {len(data)} bytes: at most {max_bytes} are read")
    data = bytes(data)
    if not data:
        raise PayloadError("empty payload: expected a map such as {\"angle_deg\": 1.0}")
    if is_json_text(data, encoding):
        # (the opening brackets bound the depth: most payloads need no walk at all)
        if data.count(b"[") + data.count(b"{") > max_depth and _json_depth(data) > max_depth:
            raise PayloadError(f"nested deeper than {max_depth} levels")
        try:
            value = json.loads(data.decode("utf-8"), parse_constant=_reject_constant)
        except (UnicodeDecodeError, ValueError) as exc:
            raise PayloadError(f"not valid JSON: {exc}") from None
    else:
        try:
            value = unpack(data)
        except SampleError as exc:
            raise PayloadError(f"neither JSON text nor msgpack: {exc}") from None
    if not isinstance(value, dict):
        raise PayloadError(f"expected a map, got {type(value).__name__}")
    if nesting_depth(value, max_depth) > max_depth:
        raise PayloadError(f"nested deeper than {max_depth} levels")
    return value


def _json_depth(data: bytes) -> int:
    """The deepest nesting of [ and { outside strings, found without parsing."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in data:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:                         # backslash
                escaped = True
            elif byte == 0x22:                         # closing quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def nesting_depth(value: Any, limit: int) -> int:
    """Nesting depth of maps and lists, counted without recursion (stops past `limit`)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, level = stack.pop()
        children: Iterable[Any]
        if isinstance(item, dict):
            children = item.values()
        elif isinstance(item, (list, tuple)):
            children = item
        else:
            continue
        deepest = max(deepest, level)
        if deepest > limit:
            return deepest
        stack.extend((child, level + 1) for child in children)
    return deepest


def _reject_constant(name: str) -> float:
    # JSON has no NaN or Infinity; Python's json accepts them unless told not to.
    raise ValueError(f"{name} is not a number")


def reply_bytes(obj: Any, like_encoding: str | None = None, like_payload: bytes | None = None) -> tuple[bytes, str]:
    """Encode a reply in the question's encoding: JSON text if it was JSON, else msgpack."""
    as_json = is_json_text(like_payload or b"", like_encoding) if (like_payload or like_encoding) else False
    if as_json:
        return json.dumps(to_jsonable(obj), separators=(",", ":")).encode(), JSON
    return msgpack.packb(obj, use_bin_type=True), MSGPACK


def to_jsonable(obj: Any) -> Any:
    """Plain JSON types: bytes as hex, non-finite floats as null."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return bytes(obj).hex()
    return obj
