"""The serial line under both Razor drivers: a pyserial URL read in timestamped chunks.

Any pyserial URL works: /dev/ttyUSB0 on the car, socket://127.0.0.1:PORT for a twin,
rfc2217://, loop://. The port is opened non-blocking and the link waits for data itself
(select on the port's file descriptor where there is one), so each wake-up takes all the
bytes that are there: pyserial's socket:// reports `in_waiting` as 0 or 1, and reading a
frame a byte at a time cost a millisecond of CPU per frame.
"""
from __future__ import annotations

import select
import time

import serial

CHUNK = 4096


class SerialLink:
    def __init__(self, url: str, baudrate: int, timeout: float = 0.1):
        self.url, self.baudrate, self.timeout = url, baudrate, timeout
        self.port: serial.SerialBase | None = None
        self._fd: int | None = None
        #: seconds one byte takes on the wire (start + 8 data + stop bits)
        self.byte_time_s = 10.0 / baudrate

    @property
    def is_open(self) -> bool:
        return self.port is not None and self.port.is_open

    def open(self) -> None:
        """Raises serial.SerialException (an OSError) if the port cannot be opened."""
        self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0,
                                          write_timeout=1.0)
        try:
            self._fd = self.port.fileno()
        except Exception:          # loop://, rfc2217://: no descriptor, poll instead
            self._fd = None

    def close(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            try:
                port.close()
            except Exception:       # closing a vanished device must not raise
                pass

    def read_chunk(self) -> tuple[bytes, int]:
        """(bytes, host time in ns UTC right after they were read); b"" after `timeout`
        without data. Raises serial.SerialException when the device is gone."""
        port = self.port
        if port is None:
            raise serial.SerialException("port is not open")
        if self._fd is not None:
            try:
                ready, _, _ = select.select([self._fd], [], [], self.timeout)
            except (OSError, ValueError) as exc:          # closed under us
                raise serial.SerialException(f"{self.url}: {exc}") from None
            if not ready:
                return b"", time.time_ns()
        else:
            data = port.read(CHUNK)
            if data:
                return data, time.time_ns()
            time.sleep(min(self.timeout, 0.002))
        if self.port is None:
            raise serial.SerialException("port closed")
        return port.read(CHUNK), time.time_ns()

    def write(self, data: bytes) -> None:
        if self.port is None:
            raise serial.SerialException("port is not open")
        self.port.write(data)
        self.port.flush()

    def discard_input(self) -> None:
        if self.port is not None:
            self.port.reset_input_buffer()
