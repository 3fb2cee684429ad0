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

Where each part lives: this module is the caster's life (listen, accept, restart, drop,
stop), its fault switches and its records; answer.py answers one connection (TLS, the
request, the source table, logins, 400/401/404/HTML); stream.py is the RTCM stream to one
client (epochs, GGA and the VRS base, the stream's faults); mountpoint.py a mountpoint and
its source-table line; clients.py what is kept of each connection.
"""
from __future__ import annotations

import collections
import logging
import select
import socket
import ssl
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from viena.common import clock

from . import protocol
from .answer import serve
from .clients import Client, Sent
from .mountpoint import Mountpoint
from .timebase import Timebase

__all__ = ["VERSIONS", "CasterTwin", "Client", "Mountpoint", "Sent"]

log = logging.getLogger(__name__)

VERSIONS = ("1.0", "2.0")
KEEP_CLOSED = 1000                # closed clients kept in `clients` (the open ones always are)


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
        self.tls_context: ssl.SSLContext | None = None
        if tls_cert is not None:
            self.tls_context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            self.tls_context.load_cert_chain(tls_cert, tls_key)
        self.rng = np.random.default_rng([seed, 0xCA57])      # the garbage fault's bytes
        # the faults: answer.py and stream.py read them at every step
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
        return self.tls_context is not None

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
                thread = clock.Thread(target=serve, args=(self, client), name=f"caster-client-{client.id}",
                                      daemon=True)
                self._threads.append(thread)
            thread.start()

    def sourcetable(self) -> str:
        """The source table's text, as GET / returns it."""
        auth = "B" if self.users else "N"
        entries = [m.entry(name, auth) for name, m in self.mountpoints.items()]
        lat, lon = (entries[0].lat_deg, entries[0].lon_deg) if entries else (0.0, 0.0)
        return protocol.table(self.host, self.port, "VIENA", "PRT", lat, lon, entries, auth)
