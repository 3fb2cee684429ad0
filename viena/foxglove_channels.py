"""The Foxglove channels of one sink, a live WebSocket server or an MCAP file, made as
the car's keys appear: what `viena foxglove` and `viena export --format foxglove` share.

`FoxgloveChannels.publish(key, encoding, data)` takes a sample as it came from zenoh or a
recording. The first sample of a key advertises its JSON channel (and the channels of
the Foxglove messages it makes: viena/foxglove_messages.py); then each sample is decoded,
checked by its schema and logged on them. A sample nobody subscribed to is not even
decoded: on the live bridge that is most of them. A sample that fails its schema is
counted in `invalid`, never sent.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import foxglove
import foxglove.channels

from viena.common.errors import SampleError
from viena.foxglove_messages import JSON_KINDS, STATEFUL_KINDS, Converter, Route, json_bytes

#: channel metadata: the zenoh encoding the key's samples came with
ENCODING_METADATA = "viena_encoding"


class _Channel(Protocol):
    """What a derived channel is to us: foxglove.Channel (JSON) or a typed one
    (foxglove.channels.*Channel), which share no base class."""

    def has_sinks(self) -> bool: ...

    def log(self, message: Any, /, *, log_time: int | None = None) -> None: ...

    def close(self) -> None: ...


@dataclass
class _KeyChannels:
    route: Route
    json: foxglove.Channel
    derived: dict[str, _Channel] = field(default_factory=dict)      # topic -> typed channel

    def __post_init__(self):
        # the SDK's own log (foxglove.Channel.log) checks the message's type every time: the
        # bytes go straight to its Rust channel
        self.json_log = self.json.base.log

    def wanted(self) -> bool:
        """Whether a sample of this key is worth converting: someone watches one of its
        channels, or later samples of other keys need it (keeps_state)."""
        return self.keeps_state or self.json.has_sinks() or self.derived_watched()

    def derived_watched(self) -> bool:
        return any(ch.has_sinks() for ch in self.derived.values())

    @property
    def keeps_state(self) -> bool:
        """Its samples feed other channels (STATEFUL_KINDS): converted even when unwatched."""
        return self.route.kind in STATEFUL_KINDS


class FoxgloveChannels:
    """Channels in one foxglove.Context, by key and encoding."""

    def wanted(self, key: str, encoding: str) -> bool:
        """Whether a sample of this key is worth handing over (its channels not advertised
        yet, or `wanted`): the converting thread skips the rest before copying anything."""
        channels = self._keys.get((key, encoding))
        return channels is None or channels.wanted()

    def __init__(self, context: foxglove.Context):
        self.context = context
        self.converter = Converter()
        self.invalid: dict[str, int] = {}
        self.logged = 0
        self._keys: dict[tuple[str, str], _KeyChannels] = {}
        self._typed: dict[str, _Channel] = {}

    def publish(self, key: str, encoding: str, data: bytes, log_time: int | None = None) -> bool:
        """Log one sample (and what it makes) if anyone listens; False if it failed its schema."""
        channels = self._keys.get((key, encoding))
        if channels is None:
            channels = self._keys[(key, encoding)] = self._advertise(key, encoding)
        json_watched = channels.json.has_sinks()
        derived_watched = channels.derived_watched()
        if not (json_watched or derived_watched or channels.keeps_state):
            return True
        try:
            value = self.converter.decode(channels.route, data)
        except SampleError:
            self.invalid[key] = self.invalid.get(key, 0) + 1
            return False
        if json_watched:
            channels.json_log(channels.route.json(value), log_time)
            self.logged += 1
        if not derived_watched:                 # only what later samples need (the origin, error counts)
            self.converter.remember(channels.route, value)
            return True
        for derived in self.converter.derived(channels.route, value):
            message = json_bytes(derived.message) if derived.kind in JSON_KINDS else derived.message
            channels.derived[derived.topic].log(message, log_time=log_time)
            self.logged += 1
        return True

    def _advertise(self, key: str, encoding: str) -> _KeyChannels:
        route = self.converter.route(key, encoding)
        schema = route.json_schema()
        metadata = {ENCODING_METADATA: encoding}
        if schema is None:                      # no known schema: schemaless JSON
            json_channel = foxglove.Channel(key, message_encoding="json", context=self.context, metadata=metadata)
        else:
            json_channel = foxglove.Channel(key, schema=schema, context=self.context, metadata=metadata)
        channels = _KeyChannels(route, json_channel)
        for topic, kind in route.topics:
            typed = self._typed.get(topic)
            if typed is None and kind in JSON_KINDS:
                typed = self._typed[topic] = foxglove.Channel(topic, schema=JSON_KINDS[kind].schema,
                                                              context=self.context)
            elif typed is None:
                make = getattr(foxglove.channels, f"{kind}Channel")
                typed = self._typed[topic] = make(topic, context=self.context)
            channels.derived[topic] = typed
        return channels

    @property
    def keys(self) -> int:
        """How many keys have a channel."""
        return len({key for key, _ in self._keys})

    def close(self) -> None:
        for channels in self._keys.values():
            channels.json.close()
        for typed in self._typed.values():
            typed.close()
        self._keys.clear()
        self._typed.clear()

