"""A local NTRIP caster, serving the base twins' RTCM 3 the way real casters do, and failing
the ways real casters fail.

    caster = CasterTwin(mountpoints={"VIENA0": Mountpoint.at(origin, baseline_m=2000)},
                        users={"rover": "secret"}).start()
    ...  # a client on ntrip://127.0.0.1:{caster.port}/VIENA0
    caster.stop()

What it answers (protocol.py): NTRIP 1.0 and 2.0, the source table, 401 for wrong
credentials, an unknown mountpoint as a v1 caster does (the source table) or a v2 one
(404), a VRS-like mountpoint (`Mountpoint(vrs=True)`, STR's NMEA flag 1) that sends
nothing until the rover's GGA arrives and then serves a virtual base at the rover's
position. TLS when given a certificate and key. Streams start at the next epoch (the base's
next whole GPS second plus its latency), with the station messages (1005/1006, 1033) first.

Faults a test flips while clients are connected (plain attributes, read at every step):
`drop_clients()` (close every client now), `drop_every_s` (close each client that long
after its stream began), `answer_html` (HTTP 200 text/html to every request),
`garbage_every_s` (bytes that are no RTCM between frames), `flood_bytes_per_s` (extra
valid observables frames of sub-second epochs, a base streaming far above 1 Hz),
`silent` (connected, streaming nothing), a mountpoint's `messages` (legacy 1004/1005 or
MSM), and `restart(down_s)` (clients dropped, connections refused for `down_s`, then the
same port again). Every `_s` is on the caster's timebase (timebase.py: real GPS time, or
faster for tests).

What it records: `clients` (each connection: peer, request, answer, the GGA lines it sent,
bytes, why it ended) and `sent` ((message number, GPS epoch, monotonic send time) per frame
sent), so a benchmark can measure a correction's age from the caster's send to the
receiver's read. One thread accepts, one serves each client; stop() joins them all and
closes every socket.
"""
from __future__ import annotations

import collections
import logging
import math
import secrets
import select
import socket
import ssl
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import pynmea2

from viena.common import clock

from . import protocol, schedule
from .base import BaseStation
from .timebase import Timebase

log = logging.getLogger(__name__)

VERSIONS = ("1.0", "2.0")
REQUEST_TIMEOUT_S = 10.0          # real seconds a connection may take to send its request
SEND_TIMEOUT_S = 5.0              # a client that takes no data for this long is dropped
MAX_LAG_EPOCHS = 5                # epochs a late client loop still sends; older ones are skipped
KEEP_CLOSED = 1000                # closed clients kept in `clients` (the open ones always are)
_TICK_S = 0.1                     # the longest a client loop waits (real s) before looking again


@dataclass(eq=False)
class Mountpoint:
    """A mountpoint: its base station and what the base sends (message -> interval s)."""
    base: BaseStation
    messages: dict[int, float] = field(default_factory=lambda: dict(schedule.RTK))
    identifier: str = "Lisboa"
    country: str = "PRT"
    network: str = "VIENA"
    vrs: bool = False               # STR NMEA 1: nothing until a GGA, then a base at the rover
    latency_s: float = 0.2          # from the epoch to the base's frames reaching the caster

    def __post_init__(self) -> None:
        self.messages = schedule.check(self.messages)
        self._frames = schedule.Frames(self.base)
        self._bitrate: dict[tuple, int] = {}

    @classmethod
    def at(cls, origin: Sequence[float], baseline_m: float = 0.0, bearing_deg: float = 0.0,
           enu_m: Sequence[float] | None = None, station_id: int = 0, seed: int = 0,
           messages: str | Mapping[int, float] = "rtk", **kwargs) -> Mountpoint:
        """A mountpoint whose base stands `baseline_m` from `origin` at `bearing_deg` (or at
        `enu_m` from it), sending the message set "rtk", "l1", "msm" or one given."""
        chosen = schedule.MESSAGE_SETS[messages] if isinstance(messages, str) else messages
        base = BaseStation.at(origin, baseline_m, bearing_deg, enu_m, station_id=station_id, seed=seed)
        return cls(base, dict(chosen), **kwargs)

    @property
    def frames(self) -> schedule.Frames:
        return self._frames

    def entry(self, name: str, authentication: str) -> protocol.StreamEntry:
        lat, lon, _ = self.base.position
        return protocol.StreamEntry(
            name, self.identifier, schedule.format_of(self.messages), schedule.format_details(self.messages),
            schedule.carrier_of(self.messages), schedule.nav_system_of(self.messages), self.network,
            self.country, lat, lon, int(self.vrs), int(self.vrs), "VienaBaseTwin", authentication,
            self.bitrate())

    def bitrate(self) -> int:
        """Bits per second of the message set, from the frames of a sample epoch."""
        key = tuple(sorted(self.messages.items()))
        if key not in self._bitrate:
            sample = schedule.Frames(self.base)
            t = 1_400_000_000                                 # a fixed epoch: the table does not change
            bits = sum(len(sample.frame(n, t)) * 8 / interval for n, interval in self.messages.items())
            self._bitrate[key] = round(bits)
        return self._bitrate[key]


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


class _Closed(Exception):
    """The connection ended (why: the message)."""


class CasterTwin:
    """An NTRIP caster on a local port (see the module's docstring)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0,
                 mountpoints: Mapping[str, Mountpoint] | None = None,
                 users: Mapping[str, str] | None = None, versions: Sequence[str] = VERSIONS,
                 tls_cert: str | None = None, tls_key: str | None = None,
                 timebase: Timebase | None = None, seed: int = 0, icy_headers: bool = False):
        bad = [v for v in versions if v not in VERSIONS]
        if bad or not versions:
            raise ValueError(f"NTRIP versions are {VERSIONS}, not {list(versions)}")
        if (tls_cert is None) != (tls_key is None):
            raise ValueError("TLS needs both a certificate and its key")
        self.host = host
        self.port = port
        self.mountpoints: dict[str, Mountpoint] = dict(mountpoints or {})
        self.users = dict(users or {})
        self.versions = tuple(versions)
        self.timebase = timebase or Timebase()
        self.icy_headers = icy_headers
        self._tls: ssl.SSLContext | None = None
        if tls_cert is not None:
            self._tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            self._tls.load_cert_chain(tls_cert, tls_key)
        self._rng = np.random.default_rng([seed, 0xCA57])
        # the faults
        self.drop_every_s = 0.0
        self.answer_html = False
        self.garbage_every_s = 0.0
        self.flood_bytes_per_s = 0.0
        self.silent = False
        # what happened
        self.clients: list[Client] = []
        self.sent: collections.deque[Sent] = collections.deque(maxlen=200_000)
        self.garbage_bytes_sent = 0
        self._lock = threading.Lock()
        self._stop = clock.Event()
        self._server: socket.socket | None = None
        self._acceptor: Any = None
        self._accepting = False
        self._threads: list[Any] = []
        self._restarts: list[Any] = []
        self._up = clock.Event()
        self._ids = 0
        self._generation = 0                # of restarts: only the last one comes back

    # -- life --------------------------------------------------------------------------------------
    @property
    def tls(self) -> bool:
        return self._tls is not None

    def url(self, mountpoint: str = "") -> str:
        return f"ntrip{'s' if self.tls else ''}://{self.host}:{self.port}/{mountpoint}"

    @property
    def is_up(self) -> bool:
        return self._up.is_set()

    def wait_up(self, timeout: float) -> bool:
        return self._up.wait(timeout)

    def start(self) -> CasterTwin:
        self._listen()
        log.info("caster twin on %s:%d, mountpoints %s, NTRIP %s%s", self.host, self.port,
                 ", ".join(self.mountpoints) or "none", "/".join(self.versions), ", TLS" if self.tls else "")
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._restarts:
            t.join(timeout=5)
        self._unlisten()
        self.drop_clients("the caster stopped")
        with self._lock:
            threads = list(self._threads)
        for t in threads:
            t.join(timeout=5)

    def __enter__(self) -> CasterTwin:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def restart(self, down_s: float = 0.0) -> None:
        """Go down now (clients dropped, the port closed: connections are refused), and
        listen again on the same port after `down_s` (timebase seconds). Returns at once;
        `wait_up()` says when it listens again."""
        self._unlisten()
        self.drop_clients("the caster restarted")
        self._generation += 1
        generation = self._generation

        def come_back() -> None:
            if not self._stop.wait(self.timebase.real_s(down_s)) and generation == self._generation:
                self._listen()
                log.info("caster twin back on port %d after %.1f s down", self.port, down_s)
        thread = clock.Thread(target=come_back, name="caster-restart", daemon=True)
        self._restarts = [t for t in self._restarts if t.is_alive()] + [thread]
        thread.start()

    def drop_clients(self, why: str = "dropped by the caster") -> int:
        """Close every client connection now; how many there were."""
        with self._lock:
            live = [c for c in self.clients if c.open and c._sock is not None]
        for c in live:
            c._kill = why
            try:
                socket.socket.shutdown(c._sock, socket.SHUT_RDWR)   # the fd's, not TLS's
            except OSError:
                pass
        return len(live)

    def active(self) -> list[Client]:
        with self._lock:
            return [c for c in self.clients if c.open]

    def _listen(self) -> None:
        if self._stop.is_set() or self._server is not None:
            return
        server = socket.create_server((self.host, self.port))
        self.port = server.getsockname()[1]
        self._server = server
        self._accepting = True
        self._acceptor = clock.Thread(target=self._accept_loop, args=(server,), name="caster-accept", daemon=True)
        self._acceptor.start()
        self._up.set()

    def _unlisten(self) -> None:
        self._up.clear()
        self._accepting = False
        if self._acceptor is not None:
            self._acceptor.join(timeout=5)
            self._acceptor = None
        if self._server is not None:
            self._server.close()
            self._server = None

    def _accept_loop(self, server: socket.socket) -> None:
        while self._accepting and not self._stop.is_set():
            ready, _, _ = select.select([server], [], [], 0.05)
            if not ready:
                continue
            try:
                conn, peer = server.accept()
            except OSError:
                continue
            with self._lock:
                self._ids += 1
                client = Client(self._ids, peer, clock.monotonic(), _sock=conn)
                closed = [c for c in self.clients if not c.open]
                if len(closed) > KEEP_CLOSED:
                    forget = {id(c) for c in closed[:len(closed) - KEEP_CLOSED]}
                    self.clients = [c for c in self.clients if id(c) not in forget]
                self.clients.append(client)
                self._threads = [t for t in self._threads if t.is_alive()]
                thread = clock.Thread(target=self._serve, args=(client,), name=f"caster-client-{client.id}",
                                      daemon=True)
                self._threads.append(thread)
            thread.start()

    # -- one client --------------------------------------------------------------------------------
    def _serve(self, client: Client) -> None:
        conn = client._sock
        why = "closed"
        try:
            conn.settimeout(SEND_TIMEOUT_S)
            if self._tls is not None:
                conn = client._sock = self._tls_handshake(client, conn)
            request = self._read_request(client, conn)
            client.request = request
            self._answer(client, conn, request)
            why = client.why_closed or "answered"
        except _Closed as closed:
            why = str(closed)
        except (OSError, ssl.SSLError) as exc:
            why = f"connection error: {exc}"
        finally:
            why = client._kill or why
            try:
                conn.close()
            except OSError:
                pass
            client.why_closed = why
            client.closed_s = clock.monotonic()
            log.info("client %d (%s:%d) %s: %s", client.id, *client.peer[:2], client.answer or "no answer", why)

    def _tls_handshake(self, client: Client, conn: socket.socket) -> ssl.SSLSocket:
        assert self._tls is not None
        try:
            return self._tls.wrap_socket(conn, server_side=True)
        except (ssl.SSLError, OSError) as exc:
            client.answer = "tls"
            raise _Closed(f"TLS handshake failed: {exc}") from None

    def _read_request(self, client: Client, conn) -> protocol.Request:
        data = b""
        deadline = clock.monotonic() + REQUEST_TIMEOUT_S
        while True:
            if client._kill:
                raise _Closed(client._kill)
            left = deadline - clock.monotonic()
            if left <= 0:
                client.answer = "timeout"
                raise _Closed(f"no request within {REQUEST_TIMEOUT_S:g} s")
            if not _readable(conn, min(left, _TICK_S)):
                continue
            more = conn.recv(4096)
            if not more:
                raise _Closed("closed before its request")
            data += more
            try:
                request = protocol.parse_request(data)
            except protocol.BadRequest as exc:
                client.answer = "400"
                self._send(client, conn, protocol.bad_request())
                raise _Closed(f"bad request: {exc}") from None
            if request is not None:
                return request

    def _answer(self, client: Client, conn, request: protocol.Request) -> None:
        v2 = (request.ntrip2 and "2.0" in self.versions) or "1.0" not in self.versions
        client.version = "2.0" if v2 else "1.0"
        client.mountpoint = request.mountpoint
        if self.answer_html:
            client.answer = "html"
            self._send(client, conn, protocol.html_page())
            return
        if request.method != "GET":
            client.answer = "400"
            self._send(client, conn, protocol.bad_request(v2))
            return
        mount = self.mountpoints.get(request.mountpoint)
        if mount is None:
            if request.mountpoint and v2:
                client.answer = "404"
                self._send(client, conn, protocol.not_found(request.mountpoint))
            else:
                client.answer = "sourcetable"
                self._send(client, conn, protocol.sourcetable(self.sourcetable(), v2))
            return
        credentials = request.credentials()
        client.user = credentials[0] if credentials else None
        if self.users and not self._authorized(credentials):
            client.answer = "401"
            self._send(client, conn, protocol.unauthorized(request.mountpoint, v2))
            return
        client.answer = "stream"
        self._send(client, conn, protocol.stream_ok(v2, self.icy_headers))
        self._stream(client, conn, mount, v2)

    def _authorized(self, credentials: tuple[str, str] | None) -> bool:
        if credentials is None or credentials[0] not in self.users:
            return False
        return secrets.compare_digest(credentials[1].encode(), self.users[credentials[0]].encode())

    def sourcetable(self) -> str:
        """The source table's text, as GET / returns it."""
        auth = "B" if self.users else "N"
        entries = [m.entry(name, auth) for name, m in self.mountpoints.items()]
        lat, lon = (entries[0].lat_deg, entries[0].lon_deg) if entries else (0.0, 0.0)
        return protocol.table(self.host, self.port, "VIENA", "PRT", lat, lon, entries, auth)

    # -- the stream ----------------------------------------------------------------------------------
    def _stream(self, client: Client, conn, mount: Mountpoint, v2: bool) -> None:
        tb = self.timebase
        pending = client.request.rest if client.request else b""
        gga_header = client.request.headers.get("ntrip-gga") if client.request else None
        if gga_header:
            self._on_gga(client, mount, gga_header)
        pending = self._read_lines(client, mount, pending)
        start = tb.now()
        next_epoch = math.floor(start) + 1
        first = True
        flood_t, next_flood, credit = start, start, 0.0
        next_garbage = None
        while True:
            if client._kill:
                raise _Closed(client._kill)
            now = tb.now()
            if self.drop_every_s > 0 and now - start >= self.drop_every_s:
                raise _Closed(f"dropped by the caster after {now - start:.1f} s (drop_every_s)")
            send_at = next_epoch + mount.latency_s
            if now >= send_at:
                behind = math.floor(now - mount.latency_s) - next_epoch
                if behind >= MAX_LAG_EPOCHS:
                    next_epoch += behind
                frames = self._frames_for(client, mount)
                if frames is not None and not self.silent:
                    batch = frames.at(mount.messages, next_epoch, first)
                    self._send_frames(client, conn, batch, next_epoch, v2)
                    first = False
                next_epoch += 1
                continue
            due = [send_at]
            if self.flood_bytes_per_s > 0 and self._frames_for(client, mount) is not None and not self.silent:
                if now >= next_flood:
                    credit = min(credit + self.flood_bytes_per_s * (now - flood_t), self.flood_bytes_per_s)
                    credit = self._flood(client, conn, mount, v2, flood_t, now, credit)
                    flood_t, next_flood = now, now + 0.1
                due.append(next_flood)
            if self.garbage_every_s > 0:
                if next_garbage is None:
                    next_garbage = now + self.garbage_every_s
                elif now >= next_garbage:
                    self._garbage(client, conn, v2)
                    next_garbage = now + self.garbage_every_s
                due.append(next_garbage)
            else:
                next_garbage = None
            if self.drop_every_s > 0:
                due.append(start + self.drop_every_s)
            wait = min(tb.real_s(min(due) - now), _TICK_S)
            if _readable(conn, wait):
                data = conn.recv(4096)
                if not data:
                    raise _Closed("closed by the client")
                pending = self._read_lines(client, mount, pending + data)

    def _frames_for(self, client: Client, mount: Mountpoint) -> schedule.Frames | None:
        """Whose frames this client gets: the mountpoint's base, or (VRS) its own virtual
        base once its GGA came; None while a VRS client has sent none."""
        return mount.frames if not mount.vrs else client._frames

    def _read_lines(self, client: Client, mount: Mountpoint, data: bytes) -> bytes:
        """The client's upstream lines (GGA); what is left of a line not yet ended."""
        *lines, rest = data.split(b"\n")
        for raw in lines:
            line = raw.strip().decode("latin-1", "replace")
            if line:
                self._on_gga(client, mount, line)
        return rest[-1024:]

    def _on_gga(self, client: Client, mount: Mountpoint, line: str) -> None:
        if "GGA" not in line[:7]:
            return
        client.gga.append(line)
        if not mount.vrs or client.base is not None:
            return
        try:
            gga = pynmea2.parse(line)
            if not int(gga.gps_qual or 0) or gga.latitude is None:
                return
            height = float(gga.altitude or 0.0) + float(gga.geo_sep or 0.0)
        except (pynmea2.ParseError, ValueError, TypeError, AttributeError):
            return
        base = mount.base
        client.base = BaseStation(gga.latitude, gga.longitude, height, station_id=base.station_id,
                                  seed=base.seed, systems=base.systems, descriptors=base.descriptors)
        client._frames = schedule.Frames(client.base)
        log.info("client %d: a virtual base at %.5f, %.5f", client.id, gga.latitude, gga.longitude)

    def _send_frames(self, client: Client, conn, batch: list[tuple[int, bytes]], epoch: float, v2: bool) -> None:
        if not batch:
            return
        data = b"".join(f for _, f in batch)
        self._record(client, [Sent(n, float(epoch), clock.monotonic()) for n, _ in batch])
        self._send(client, conn, protocol.chunk(data) if v2 else data)

    def _record(self, client: Client, records: list[Sent]) -> None:
        """Frames about to be handed to the socket: that instant is their send time."""
        client.sent.extend(records)
        self.sent.extend(records)

    def _flood(self, client: Client, conn, mount: Mountpoint, v2: bool, flood_t: float, now: float,
               credit: float) -> float:
        """Observables of sub-second epochs between `flood_t` and `now`, as many bytes as
        the flood's `credit` holds (a base streaming far faster than 1 Hz); the credit left."""
        frames = self._frames_for(client, mount)
        number = next((n for n in mount.messages if n in schedule.OBSERVABLES), None)
        if number is None or frames is None:
            return 0.0
        size = len(frames.frame(number, float(math.floor(now))))
        count = int(credit // size)
        if count == 0:
            return credit
        step = (now - flood_t) / count
        batch, epochs = [], []
        for k in range(1, count + 1):
            epoch = round(flood_t + k * step, 3)
            batch.append((number, frames.frame(number, epoch)))
            epochs.append(epoch)
            credit -= size
        data = b"".join(f for _, f in batch)
        sent_at = clock.monotonic()
        self._record(client, [Sent(n, e, sent_at) for (n, _), e in zip(batch, epochs)])
        self._send(client, conn, protocol.chunk(data) if v2 else data)
        client.flood_bytes += len(data)
        return credit

    def _garbage(self, client: Client, conn, v2: bool) -> None:
        """Bytes that are no RTCM (no 0xD3 preamble among them) between two frames."""
        size = int(self._rng.integers(16, 65))
        values = self._rng.integers(0, 255, size)
        data = bytes(int(v) + (v >= 0xD3) for v in values)
        self._send(client, conn, protocol.chunk(data) if v2 else data)
        client.garbage_bytes += size
        self.garbage_bytes_sent += size

    def _send(self, client: Client, conn, data: bytes) -> None:
        try:
            conn.sendall(data)
        except TimeoutError:
            raise _Closed(f"the client took no data for {SEND_TIMEOUT_S:g} s") from None
        except OSError as exc:
            raise _Closed(client._kill or f"send failed: {exc}") from None
        client.bytes_sent += len(data)


def _readable(conn, timeout: float) -> bool:
    if isinstance(conn, ssl.SSLSocket) and conn.pending():
        return True
    try:
        ready, _, _ = select.select([conn], [], [], max(0.0, timeout))
    except (OSError, ValueError):
        return True                      # closed under us: let recv say so
    return bool(ready)
