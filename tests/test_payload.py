"""Payloads typed by people (JSON text) or sent by programs (msgpack)."""
import json

import msgpack
import pytest

from viena.common import zenoh_cli_codec
from viena.common.errors import PayloadError
from viena.common.payload import parse_payload, reply_bytes


def test_json_text_and_msgpack_give_the_same_map():
    want = {"angle_deg": 5, "lease": "abc"}
    assert parse_payload(json.dumps(want).encode()) == want
    assert parse_payload(b'  {"angle_deg": 5, "lease": "abc"}\n') == want
    assert parse_payload(msgpack.packb(want)) == want


@pytest.mark.parametrize("data, message", [
    (b"", "empty payload"),
    (b'{"angle_deg": NaN}', "not valid JSON"),
    (b'{"angle_deg": Infinity}', "not valid JSON"),
    (b'{"angle_deg": ', "not valid JSON"),
    (b"[1, 2]", "expected a map"),
    (b"\xc1\xc1", "neither JSON text nor msgpack"),
    (msgpack.packb(5), "expected a map"),
    (b"\xff\xfe{", "neither JSON text nor msgpack"),
])
def test_bad_payloads_say_what_is_wrong(data, message):
    with pytest.raises(PayloadError, match=message):
        parse_payload(data)


def test_reply_in_the_question_encoding():
    body, enc = reply_bytes({"status": "accepted"}, None, b'{"arm": true}')
    assert enc == "application/json" and json.loads(body) == {"status": "accepted"}
    body, enc = reply_bytes({"status": "accepted"}, None, msgpack.packb({"arm": True}))
    assert enc == "application/msgpack" and msgpack.unpackb(body) == {"status": "accepted"}


def test_zenoh_cli_codec_round_trip():
    data = zenoh_cli_codec.encode("k", '{"a": 1, "b": [1.5, "x"]}')
    assert msgpack.unpackb(data) == {"a": 1, "b": [1.5, "x"]}
    assert json.loads(zenoh_cli_codec.decode("k", data)) == {"a": 1, "b": [1.5, "x"]}
    assert json.loads(zenoh_cli_codec.decode("k", b'{"status": "ok"}')) == {"status": "ok"}
