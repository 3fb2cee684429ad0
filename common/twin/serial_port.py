"""How a serial device twin meets its driver: a byte protocol engine served on TCP.

A twin is written as a small state machine (`ByteTwin`) with no sockets in it, so tests can
drive it directly. `SerialEndpoint` puts one on a TCP port that the unchanged driver opens
as the pyserial URL `socket://127.0.0.1:PORT`, exactly as it opens `/dev/ttyUSB0` on the car.
"""
from __future__ import annotations

import logging
import selectors
import socket
import threading
import time

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
        self.bytes_sent = 0

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
                    conn, _addr = self._server.accept()
                    if client is not None:          # a new host takes the line over
                        sel.unregister(client)
                        client.close()
                    client = conn
                    client.setblocking(False)
                    client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    sel.register(client, selectors.EVENT_READ)
                    self.twin.on_connect(time.monotonic())
                    log.info("%s: host connected", self.name)
                elif client is not None:
                    data = self._recv(client)
                    if data is None:
                        sel.unregister(client)
                        client.close()
                        client = None
                        log.info("%s: host disconnected", self.name)
                    else:
                        self.twin.feed(data, time.monotonic())
            if client is not None:
                out = self.twin.poll(time.monotonic())
                if out and not self._send(client, out):
                    sel.unregister(client)
                    client.close()
                    client = None
        if client is not None:
            client.close()
        sel.close()

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
