"""A small client of the Foxglove WebSocket protocol, written here so that the tests check
the bridge as Foxglove sees it, not through the SDK that serves it.

The protocol (github.com/foxglove/ws-protocol, docs/spec.md), as far as these tests use
it: JSON text messages (`serverInfo`, `advertise`, `advertiseServices`, `subscribe`) and
binary frames: 0x01 message data (u32 subscription id, u64 log time ns, payload), client
0x02 service call request (u32 service id, u32 call id, u32 encoding length, encoding,
payload) and server 0x03 service call response (the same layout). Little-endian. The
SDK's server names it `foxglove.sdk.v1` (formerly `foxglove.websocket.v1`, the same
protocol); the client offers both names, as Foxglove and Lichtblick do.

Also: `decoder(channel)` turns a channel's messages into values by its own advertised
schema: JSON checked with jsonschema, protobuf parsed with the channel's descriptors; and
`read_all(path)`, `as_advertised(channel, schema)` do the same for an MCAP file's channels.
"""
from __future__ import annotations

import base64
import json
import re
import socket
import struct
import time
from contextlib import ExitStack
from dataclasses import dataclass

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
#: the SDK server's status when it refuses a subscription
UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")
MESSAGE_DATA, SERVICE_CALL_REQUEST, SERVICE_CALL_RESPONSE = 0x01, 0x02, 0x03


@dataclass
class Message:
    channel: dict
    log_time: int
    payload: bytes


class FoxgloveClient:
    """One connection. `receive_buffer`: the socket's receive buffer in bytes, small for a
    client that should look slow to the server."""

    def __init__(self, port: int, host: str = "127.0.0.1", receive_buffer: int | None = None):
        from websockets.sync.client import connect

        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if receive_buffer:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        sock.settimeout(10)
        sock.connect((host, port))
        sock.settimeout(None)
        # max_queue=1: frames stay in the socket until read, as in a stalled browser tab;
        # close_timeout=1: a client going away does not wait 10 s for the closing handshake
        # behind a stalled client's backlog (the server then sees the connection drop)
        self._stack = ExitStack()
        self.ws = self._stack.enter_context(connect(f"ws://{host}:{port}", sock=sock, subprotocols=SUBPROTOCOLS,
                                                    max_size=None, max_queue=1, compression=None,
                                                    ping_interval=None, close_timeout=1))
        self.subprotocol = self.ws.subprotocol
        self.server_info: dict = {}
        self.channels: dict[int, dict] = {}
        self.services: dict[str, dict] = {}
        self.statuses: list[dict] = []
        self._subscriptions: dict[int, dict] = {}
        self._asked_again: dict[int, int] = {}
        self._next_id = 1
        self._pending: list[Message] = []
        self._responses: dict[int, tuple[str, bytes]] = {}

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- reading -------------------------------------------------------------------------
    def _handle(self, frame) -> None:
        if isinstance(frame, str):
            op = json.loads(frame)
            if op["op"] == "serverInfo":
                self.server_info = op
            elif op["op"] == "advertise":
                self.channels.update({c["id"]: c for c in op["channels"]})
            elif op["op"] == "unadvertise":
                for cid in op["channelIds"]:
                    self.channels.pop(cid, None)
            elif op["op"] == "advertiseServices":
                self.services.update({s["name"]: s for s in op["services"]})
            elif op["op"] == "status":
                self.statuses.append(op)
                unknown = UNKNOWN_CHANNEL.fullmatch(op.get("message", ""))
                if unknown:
                    self._subscribe_again(int(unknown.group(1)))
            return
        opcode = frame[0]
        if opcode == MESSAGE_DATA:
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            channel = self._subscriptions.get(sub_id)
            if channel is not None:
                self._pending.append(Message(channel, log_time, bytes(frame[13:])))
        elif opcode == SERVICE_CALL_RESPONSE:
            _service, call, n = struct.unpack_from("<III", frame, 1)
            self._responses[call] = (frame[13:13 + n].decode(), bytes(frame[13 + n:]))

    def pump(self, timeout: float) -> bool:
        """Handle one frame if one comes within `timeout` s."""
        try:
            frame = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return False
        self._handle(frame)
        return True

    def wait_for(self, done, timeout: float = 20.0) -> bool:
        end = time.monotonic() + timeout
        while not done():
            left = end - time.monotonic()
            if left <= 0:
                return False
            self.pump(min(left, 0.5))
        return True

    def wait_for_topics(self, topics, timeout: float = 30.0) -> bool:
        return self.wait_for(lambda: set(topics) <= {c["topic"] for c in self.channels.values()}, timeout)

    def channel(self, topic: str) -> dict:
        return next(c for c in self.channels.values() if c["topic"] == topic)

    # -- subscribing -----------------------------------------------------------------------
    def subscribe(self, channels) -> None:
        subs = []
        for channel in channels:
            self._subscriptions[self._next_id] = channel
            subs.append({"id": self._next_id, "channelId": channel["id"]})
            self._next_id += 1
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def _subscribe_again(self, channel_id: int) -> None:
        """The server refused a subscription to a channel it had advertised ("Unknown
        channel ID": once, on a busy machine, to a subscription made while it advertised
        its channels): ask again, a few times at most, while the channel is advertised."""
        subs = [{"id": sid, "channelId": channel_id} for sid, c in self._subscriptions.items()
                if c["id"] == channel_id]
        if not subs or channel_id not in self.channels or self._asked_again.get(channel_id, 0) >= 5:
            return
        self._asked_again[channel_id] = self._asked_again.get(channel_id, 0) + 1
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, seconds: float) -> list[Message]:
        """Every message that arrives in the next `seconds` (and any already read)."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.pump(min(left, 0.2))
        out, self._pending = self._pending, []
        return out

    def collect(self, done, timeout: float = 30.0) -> list[Message]:
        """Messages until `done(messages)` says enough or `timeout` s pass."""
        got: list[Message] = []
        end = time.monotonic() + timeout
        while not done(got) and time.monotonic() < end:
            self.pump(0.2)
            got.extend(self._pending)
            self._pending = []
        return got

    # -- services --------------------------------------------------------------------------
    def call(self, name: str, payload: bytes, encoding: str = "json", timeout: float = 10.0) -> tuple[str, bytes]:
        service = self.services[name]
        call_id = self._next_id
        self._next_id += 1
        enc = encoding.encode()
        self.ws.send(bytes([SERVICE_CALL_REQUEST]) + struct.pack("<III", service["id"], call_id, len(enc))
                     + enc + payload)
        assert self.wait_for(lambda: call_id in self._responses, timeout), f"no answer from {name}"
        return self._responses.pop(call_id)


def decoder(channel: dict):
    """A function bytes -> value for the channel's messages, checked by its advertised
    schema: JSON against its JSON Schema (jsonschema raises ValidationError), protobuf
    parsed with the FileDescriptorSet the channel carries (raises DecodeError)."""
    if channel["encoding"] == "json":
        import jsonschema

        schema = json.loads(channel["schema"]) if channel.get("schema") else {}
        validator = jsonschema.Draft202012Validator(schema)

        def decode_json(data: bytes):
            value = json.loads(data)
            validator.validate(value)
            return value
        return decode_json
    if channel["encoding"] == "protobuf":
        return protobuf_decoder(channel["schemaName"], base64.b64decode(channel["schema"]))
    raise AssertionError(f"{channel['topic']}: unknown encoding {channel['encoding']!r}")


def protobuf_decoder(name: str, descriptor_set: bytes):
    """bytes -> protobuf message of type `name`, from a serialized FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    return cls.FromString


def read_all(path):
    """(summary, [(schema, channel, message)]) of an MCAP file through the mcap library's own reader."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        return summary, list(reader.iter_messages())


def as_advertised(channel, schema) -> dict:
    """An MCAP channel as the WebSocket protocol advertises it, for the same decoder."""
    data = schema.data if schema else b""
    return {"topic": channel.topic, "encoding": channel.message_encoding,
            "schemaName": schema.name if schema else "",
            "schema": base64.b64encode(data).decode() if channel.message_encoding == "protobuf" else data.decode()}
