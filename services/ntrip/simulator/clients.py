"""What the caster twin knows of each connection (`Client`, and the frames it was `Sent`),
and the two socket steps every part of serving one takes: send, and wait to read."""
from __future__ import annotations

import collections
import select
import ssl
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from . import protocol, schedule
from .base import BaseStation

SEND_TIMEOUT_S = 5.0              # a client that takes no data for this long is dropped
TICK_S = 0.1                      # the longest a client loop waits (real s) before looking again


class Sent(NamedTuple):
    """One frame sent: its message number, its epoch (GPS s), when it went (monotonic s)."""
    number: int
    epoch_gps_s: float
    monotonic_s: float


@dataclass(eq=False)
class Client:
    """One connection, as the caster saw it."""
    id: int
    peer: tuple
    connected_s: float                          # monotonic
    request: protocol.Request | None = None
    mountpoint: str = ""
    version: str = ""                           # what the caster answered in: "1.0" or "2.0"
    user: str | None = None
    answer: str = ""                            # stream, sourcetable, 401, 404, 400, html, timeout, tls
    gga: collections.deque[str] = field(default_factory=lambda: collections.deque(maxlen=10_000))
    sent: collections.deque[Sent] = field(default_factory=lambda: collections.deque(maxlen=100_000))
    bytes_sent: int = 0
    garbage_bytes: int = 0
    flood_bytes: int = 0
    closed_s: float | None = None
    why_closed: str = ""
    base: BaseStation | None = None             # a VRS mountpoint's virtual base
    _frames: schedule.Frames | None = field(default=None, repr=False)
    _sock: Any = field(default=None, repr=False)
    _kill: str = field(default="", repr=False)

    @property
    def open(self) -> bool:
        return self.closed_s is None


class Closed(Exception):
    """The connection ended (why: the message)."""


def send(client: Client, conn, data: bytes) -> None:
    """All of `data` to the client, counted; a client gone or too slow ends the connection."""
    try:
        conn.sendall(data)
    except TimeoutError:
        raise Closed(f"the client took no data for {SEND_TIMEOUT_S:g} s") from None
    except OSError as exc:
        raise Closed(client._kill or f"send failed: {exc}") from None
    client.bytes_sent += len(data)


def readable(conn, timeout: float) -> bool:
    if isinstance(conn, ssl.SSLSocket) and conn.pending():
        return True
    try:
        ready, _, _ = select.select([conn], [], [], max(0.0, timeout))
    except (OSError, ValueError):
        return True                      # closed under us: let recv say so
    return bool(ready)
