"""Payloads typed by people: JSON text from the `zenoh` CLI, or msgpack from programs.

The `zenoh` CLI sends no encoding with `put`/`get`, so the bytes themselves decide:
a msgpack map starts with 0x80-0x8f, 0xde or 0xdf, while JSON text starts with `{`.
A reply goes back in the encoding the question came in.
"""
from __future__ import annotations

import json
import math
from typing import Any

import msgpack

from viena.common.errors import PayloadError
from viena.common.schema import MSGPACK, SampleError, unpack

JSON = "application/json"


def is_json_text(data: bytes, encoding: str | None = None) -> bool:
    if encoding:
        if encoding.startswith(MSGPACK):
            return False
        if encoding.startswith(("application/json", "text/")):
            return True
    head = bytes(data[:64]).lstrip()
    return head[:1] in (b"{", b"[")


def parse_payload(data: bytes | bytearray | memoryview, encoding: str | None = None) -> dict:
    """A map from JSON text or msgpack; PayloadError saying what is wrong otherwise."""
    data = bytes(data)
    if not data:
        raise PayloadError("empty payload: expected a map such as {\"angle_deg\": 1.0}")
    if is_json_text(data, encoding):
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
    return value


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
