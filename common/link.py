"""The byte link under every serial device: one seam (`Link`), one implementation per transport.

Modelled on python-can's ``BusABC``: drivers are written against `Link` (open, read, write,
close) and a transport fills in a few primitives (`_open`, `_read`, `_write`, `_close`).
pyserial (`SerialLink`) reaches every cable the car and the twins use through a URL:
``/dev/ttyUSB0`` on the car, ``socket://127.0.0.1:PORT`` for a twin, ``rfc2217://host:port``
for a serial server, ``loop://`` for a loopback. ``mem://NAME`` is a twin in this process,
reached without a socket (lockstep/links.py: the car on a virtual clock). `open_link` picks
the transport by URL, so a driver never names one.

A link is pulled: ``read(timeout_s)`` returns what has arrived as a `Chunk`, stamped with the
host clock the moment the read returned (the receive time of the chunk's last byte). A
driver that wants its bytes pushed runs a `LinkReader` (link_reader.py) over the link, as
python-can's ``Notifier`` runs over a bus. A port that fails raises
``serial.SerialException`` (an OSError); what happens next is its owner's business (see
supervisor.py). No zenoh here.
"""
from __future__ import annotations

import logging
import select
import threading
from abc import ABC, abstractmethod
from typing import NamedTuple
from urllib.parse import urlsplit

import serial

from viena.common import clock

log = logging.getLogger(__name__)

#: the most one read takes at once
CHUNK = 4096
#: how long a transport without a file descriptor (loop://, rfc2217://) sleeps when empty
POLL_S = 0.002
#: a write that cannot finish in this long fails (a stuck USB adapter)
WRITE_TIMEOUT_S = 1.0
#: the rate a link opens at unless told (a NovAtel's factory rate)
DEFAULT_BAUDRATE = 9600
#: the scheme of the in-process links (lockstep/links.py)
MEMORY_SCHEME = "mem"


class Chunk(NamedTuple):
    """Bytes as they arrived, with the host time (ns UTC) the read returned them."""

    data: bytes
    t_host_ns: int


class Link(ABC):
    """A byte stream to one device. Subclasses implement one transport."""

    def __init__(self, url: str, baudrate: int):
        self.url = url
        self.baudrate = baudrate
        self._write_lock = threading.Lock()     # commands may come from several threads

    # -- what a transport provides ------------------------------------------------------
    @property
    @abstractmethod
    def is_open(self) -> bool: ...

    @abstractmethod
    def _open(self) -> None:
        """Open at `self.baudrate`; raise OSError when the device is not there."""

    @abstractmethod
    def _read(self, timeout_s: float) -> bytes:
        """What has arrived, waiting at most `timeout_s` for the first byte; b"" if nothing
        did. Raise OSError when the device is gone."""

    @abstractmethod
    def _write(self, data: bytes) -> None:
        """Send all of `data`; raise OSError when the device is gone."""

    @abstractmethod
    def _close(self) -> None:
        """Release the device; never raises."""

    def _apply_baudrate(self) -> None:  # noqa: B027 (optional hook: transports without rates keep it)
        """Make the open port run at `self.baudrate` (a transport without rates ignores it)."""

    @property
    def carries_break(self) -> bool:
        """Whether `send_break` reaches the device."""
        return False

    def send_break(self, duration_s: float) -> None:
        raise NotImplementedError(f"{type(self).__name__} cannot send a break")

    # -- what drivers use ---------------------------------------------------------------
    @property
    def byte_time_s(self) -> float:
        """Seconds one byte takes on the wire at the current rate (start + 8 data + stop bits)."""
        return 10.0 / self.baudrate

    def open(self, baudrate: int | None = None) -> None:
        """(Re)open the link, at `baudrate` if given; OSError when it cannot be opened."""
        if baudrate is not None:
            self.baudrate = baudrate
        self.close()
        self._open()

    def close(self) -> None:
        self._close()

    def read(self, timeout_s: float) -> Chunk:
        """The bytes that have arrived (b"" after up to `timeout_s` without any), stamped."""
        if not self.is_open:
            raise serial.PortNotOpenError()
        data = self._read(timeout_s)
        return Chunk(data, clock.time_ns())

    def write(self, data: bytes) -> None:
        if not self.is_open:
            raise serial.PortNotOpenError()
        with self._write_lock:
            self._write(data)

    def set_baudrate(self, baudrate: int) -> None:
        """Change the rate of the open port at once, without closing it (closing would drop
        DTR and lose what is in flight)."""
        if not self.is_open:
            raise serial.PortNotOpenError()
        self.baudrate = baudrate
        self._apply_baudrate()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r}, {self.baudrate})"


class SerialLink(Link):
    """A pyserial URL. The port is opened non-blocking and the link waits for data itself
    (select on the port's file descriptor where there is one), so each wake-up takes all the
    bytes that are there: pyserial's socket:// reports `in_waiting` as 0 or 1, and reading a
    frame a byte at a time cost a millisecond of CPU per frame."""

    def __init__(self, url: str, baudrate: int = DEFAULT_BAUDRATE):
        super().__init__(url, baudrate)
        self._port: serial.SerialBase | None = None
        self._fd: int | None = None

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    @property
    def carries_break(self) -> bool:
        """pyserial's socket:// and loop:// ignore breaks."""
        return urlsplit(self.url).scheme not in ("socket", "loop")

    def _open(self) -> None:
        self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0,
                                           write_timeout=WRITE_TIMEOUT_S)
        try:
            self._fd = self._port.fileno()
        except Exception:           # noqa: BLE001 - loop://, rfc2217://: no descriptor, poll
            self._fd = None

    def _read(self, timeout_s: float) -> bytes:
        port = self._opened()
        if self._fd is None:
            data = port.read(CHUNK)
            if not data:
                clock.sleep(min(timeout_s, POLL_S))
            return data
        try:
            ready, _, _ = select.select([self._fd], [], [], timeout_s)
        except (OSError, ValueError) as exc:               # closed under us
            raise serial.SerialException(f"{self.url}: {exc}") from None
        return port.read(CHUNK) if ready else b""

    def _write(self, data: bytes) -> None:
        port = self._opened()
        port.write(data)
        port.flush()

    def _apply_baudrate(self) -> None:
        self._opened().baudrate = self.baudrate     # pyserial reconfigures the open port

    def send_break(self, duration_s: float) -> None:
        self._opened().send_break(duration_s)

    def _opened(self) -> serial.SerialBase:
        """The port, or PortNotOpenError (another thread may close it at any moment)."""
        port = self._port
        if port is None:
            raise serial.PortNotOpenError()
        return port

    def _close(self) -> None:
        port, self._port, self._fd = self._port, None, None
        if port is not None:
            try:
                port.close()
            except Exception as exc:  # noqa: BLE001 - closing a vanished device must not raise
                log.debug("closing %s: %s", self.url, exc)


def open_link(url: str, baudrate: int | None = None) -> Link:
    """The link for a URL, not yet opened: ``mem://NAME`` the twin served in this process
    under NAME (see lockstep/links.py), anything else a pyserial `SerialLink`."""
    rate = DEFAULT_BAUDRATE if baudrate is None else baudrate
    if urlsplit(url).scheme == MEMORY_SCHEME:
        from viena.common.lockstep.links import MemoryLink  # only a simulation needs it
        return MemoryLink(url, rate)
    return SerialLink(url, rate)
