"""A serial link given by a pyserial URL, read by one thread.

``/dev/ttyUSB0``, ``socket://host:port`` and ``rfc2217://host:port`` all open through
``serial.serial_for_url``. The reader thread stamps every chunk with the host clock the
moment the read returns (the receive time of the chunk's last byte) and hands it on; a
port that fails is reported once and the thread ends, so the owner decides what next.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable
from urllib.parse import urlsplit

import serial

log = logging.getLogger(__name__)

#: How long one read may block: bounds how quickly close() stops the thread.
READ_TIMEOUT_S = 0.05


def carries_break(url: str) -> bool:
    """Whether a serial break reaches the device: pyserial's socket:// ignores breaks."""
    return urlsplit(url).scheme not in ("socket", "loop")


class SerialLink:
    """Open/close a pyserial URL and pump its bytes to ``on_data(data, t_host_ns)``."""

    def __init__(self, url: str, on_data: Callable[[bytes, int], None],
                 on_error: Callable[[Exception], None] | None = None, name: str = "serial"):
        self.url = url
        self._on_data = on_data
        self._on_error = on_error
        self._name = name
        self._port: serial.SerialBase | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._write_lock = threading.Lock()
        # socket:// reports in_waiting as 0 or 1 only: read the rest without blocking
        self._drain_socket = urlsplit(url).scheme == "socket"

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    @property
    def baudrate(self) -> int | None:
        return self._port.baudrate if self._port else None

    def open(self, baudrate: int) -> None:
        """Open the port and start the reader; SerialException if it cannot be opened."""
        self.close()
        self._port = serial.serial_for_url(self.url, baudrate=baudrate, timeout=READ_TIMEOUT_S,
                                           write_timeout=1.0)
        self._stop.clear()
        self._thread = threading.Thread(target=self._read_loop, args=(self._port,),
                                        name=f"{self._name}-reader", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=1.0)
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError) as exc:
                log.debug("closing %s: %s", self.url, exc)

    def write(self, data: bytes) -> None:
        port = self._port
        if port is None:
            raise serial.PortNotOpenError()
        with self._write_lock:
            port.write(data)
            port.flush()

    def set_baudrate(self, baudrate: int) -> None:
        """Reconfigure the open port; pyserial applies the new rate at once, without
        closing the device (closing would drop DTR and lose what is in flight)."""
        if self._port is None:
            raise serial.PortNotOpenError()
        self._port.baudrate = baudrate

    def send_break(self, duration_s: float) -> None:
        if self._port is None:
            raise serial.PortNotOpenError()
        self._port.send_break(duration_s)

    def _read_chunk(self, port: serial.SerialBase) -> bytes:
        """Block (up to READ_TIMEOUT_S) for the first byte, then take all that is there."""
        data = port.read(port.in_waiting or 1)
        if data and self._drain_socket:
            port.timeout = 0
            try:
                data += port.read(65536)
            finally:
                port.timeout = READ_TIMEOUT_S
        return data

    def _read_loop(self, port: serial.SerialBase) -> None:
        while not self._stop.is_set():
            try:
                data = self._read_chunk(port)
            except Exception as exc:  # noqa: BLE001 - any failure of the port ends the link
                if not self._stop.is_set():
                    log.debug("%s: reader stopped: %r", self.url, exc)
                    if self._on_error is not None:
                        self._on_error(exc)
                return
            if data:
                try:
                    self._on_data(data, time.time_ns())
                except Exception:  # noqa: BLE001 - a consumer's bug must not kill the link
                    log.exception("%s: handling received bytes failed", self.url)
