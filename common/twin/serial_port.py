"""How a serial device twin meets its driver: a byte protocol engine served on TCP.

A twin is written as a small state machine (`ByteTwin`) with no sockets in it, so tests can
drive it directly. `SerialEndpoint` puts one on a TCP port that the unchanged driver opens
as the pyserial URL `socket://127.0.0.1:PORT`, exactly as it opens `/dev/ttyUSB0` on the car.

Like a serial port, it has one host at a time: whoever opens it while another holds it is
refused (the connection closed at once, a log line), so no process takes the line over
from the service; a host that closed its end makes room at once, for its own reconnect.
On loopback only the twin's own user is served (peers.py).
"""
from __future__ import annotations

import logging
import selectors
import socket
import threading
import time

from viena.common.log import Throttled
from viena.common.twin.peers import refusal

log = logging.getLogger(__name__)


class ByteTwin:
    """A device behind a serial line. Subclasses override what their device does."""

    def on_connect(self, now_s: float) -> None:
        """The host opened the port (a fresh cable): reset line state."""

    def feed(self, data: bytes, now_s: float) -> None:
        """Bytes the host wrote."""

    def poll(self, now_s: float) -> bytes:
        """Bytes the device has sent by `now_s` (monotonic seconds)."""
        return b""

    def next_due(self, now_s: float) -> float:
        """When `poll` next has something to say (monotonic seconds)."""
        return now_s + 0.01


class TwinWrapper(ByteTwin):
    """A twin around another one, for benches and tests that watch or damage the line:
    everything passes through unless a subclass overrides it (usually `poll`)."""

    def __init__(self, inner: ByteTwin):
        self.inner = inner

    def on_connect(self, now_s: float) -> None:
        self.inner.on_connect(now_s)

    def feed(self, data: bytes, now_s: float) -> None:
        self.inner.feed(data, now_s)

    def poll(self, now_s: float) -> bytes:
        return self.inner.poll(now_s)

    def next_due(self, now_s: float) -> float:
        return self.inner.next_due(now_s)


class SerialEndpoint:
    """Serves one twin on a TCP port, one host at a time, like a serial cable."""

    def __init__(self, twin: ByteTwin, host: str = "127.0.0.1", port: int = 0, name: str = "twin"):
        self.twin = twin
        self.name = name
        self._server = socket.create_server((host, port), reuse_port=False)
        self._server.setblocking(False)
        self.host, self.port = self._server.getsockname()[:2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"endpoint-{name}", daemon=True)
        self._refused = Throttled(log, f"{name}: connection refused")
        self.bytes_sent = 0
        self.refused = 0                      # connections closed unserved

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def start(self) -> SerialEndpoint:
        self._thread.start()
        log.info("%s serving on %s", self.name, self.url)
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._server.close()

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._server, selectors.EVENT_READ)
        client: socket.socket | None = None
        while not self._stop.is_set():
            now = time.monotonic()
            timeout = 0.05 if client is None else min(0.05, max(0.0, self.twin.next_due(now) - now))
            for key, _ in sel.select(timeout):
                if key.fileobj is self._server:
                    client = self._accept(sel, client)
                elif client is not None and not self._serve(client):
                    sel.unregister(client)
                    client.close()
                    client = None
                    log.info("%s: host disconnected", self.name)
            if client is not None:
                out = self.twin.poll(time.monotonic())
                if out and not self._send(client, out):
                    sel.unregister(client)
                    client.close()
                    client = None
        if client is not None:
            client.close()
        sel.close()

    def _accept(self, sel, client: socket.socket | None) -> socket.socket | None:
        """The host after a connection came: the new one, or (if refused) the one there was."""
        try:
            conn, peer = self._server.accept()
        except BlockingIOError:
            return client
        if client is not None and not self._serve(client):      # it closed its end just before
            sel.unregister(client)
            client.close()
            client = None
            log.info("%s: host disconnected", self.name)
        why = refusal(conn)
        if why is None and client is not None:
            why = "another host holds the line (one at a time, as on a serial port)"
        if why is not None:
            self.refused += 1                 # counted before the peer can see it closed
            self._refused.log(why, f"from {peer[0]}:{peer[1]}")
            conn.close()
            return client
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sel.register(conn, selectors.EVENT_READ)
        self.twin.on_connect(time.monotonic())
        log.info("%s: host connected", self.name)
        return conn

    def _serve(self, client: socket.socket) -> bool:
        """What the host wrote, fed to the twin; False once it has closed its end."""
        while True:
            data = self._recv(client)
            if data is None:
                return False
            if not data:
                return True
            self.twin.feed(data, time.monotonic())

    @staticmethod
    def _recv(conn: socket.socket) -> bytes | None:
        try:
            data = conn.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            return None
        return data or None

    def _send(self, conn: socket.socket, data: bytes) -> bool:
        try:
            conn.setblocking(True)
            conn.settimeout(1.0)
            conn.sendall(data)
            self.bytes_sent += len(data)
            return True
        except OSError:
            return False
        finally:
            conn.setblocking(False)


def serve_twin(twin: ByteTwin, name: str, host: str, port: int):
    """A twin's cable: on TCP at host:port, or in this process when the sim's host is
    "mem" (the lockstep runner, viena.common.lockstep.links), where drivers open it as
    `mem://NAME`."""
    if host == "mem":
        from viena.common.lockstep.links import MemoryEndpoint

        return MemoryEndpoint(twin, name).start()
    return SerialEndpoint(twin, host, port, name).start()
