"""The `msgpack` codec for the `zenoh` CLI (zenoh-cli plugin entry points).

    zenoh --mode client --connect tcp/127.0.0.1:7447 subscribe -k 'viena/**' --decoder msgpack
    zenoh --mode client --connect tcp/127.0.0.1:7447 put -k KEY --encoder msgpack -v '{"a": 1}'
"""
from __future__ import annotations

import json

import msgpack

from viena.common.payload import to_jsonable
from viena.common.schema import unpack


def encode(key: str, value: str) -> bytes:
    """JSON text typed by a person -> msgpack."""
    return msgpack.packb(json.loads(value), use_bin_type=True)


def decode(key: str, value: bytes) -> str:
    """msgpack -> one line of JSON (JSON text passes through, so replies in JSON print too)."""
    data = bytes(value)
    if data[:1] in (b"{", b"["):
        return json.dumps(json.loads(data), separators=(", ", ": "))
    return json.dumps(to_jsonable(unpack(data, key)), separators=(", ", ": "))
