"""A `socket://` port that reads what the socket holds in one go.

python-can's slcan interface asks a port's `in_waiting`, then reads one byte at a time.
pyserial's own socket port answers each of those with a select(), and each byte with a
recv() as well: three system calls a byte, some 18,000 a second for the simulated
drive's CAN traffic, a tenth of a core. This port keeps what one recv() brings and serves
reads from it; the rest (URL, open, write, close) is pyserial's. Only the simulated car
needs it: on the car the steering talks socketcan.
"""
from __future__ import annotations

import select

from serial.serialutil import PortNotOpenError, SerialException, Timeout
from serial.urlhandler import protocol_socket

#: the most one recv() takes
CHUNK = 4096


class Serial(protocol_socket.Serial):
    """pyserial's socket port, with what has arrived held in a buffer of its own."""

    def open(self) -> None:
        self._held = bytearray()
        super().open()

    @property
    def in_waiting(self) -> int:
        self._receive(0)
        return len(self._held)

    def read(self, size: int = 1) -> bytes:
        timeout = Timeout(self._timeout)
        while len(self._held) < size and self._receive(timeout.time_left()) and not timeout.expired():
            pass
        data = bytes(self._held[:size])
        del self._held[:size]
        return data

    def reset_input_buffer(self) -> None:
        self._held.clear()
        super().reset_input_buffer()

    def _receive(self, wait: float | None) -> bool:
        """Add what arrives within `wait` s (None: until something does); False if nothing."""
        if not self.is_open:
            raise PortNotOpenError()
        ready, _, _ = select.select([self._socket], [], [], wait)
        if not ready:
            return False
        try:
            data = self._socket.recv(CHUNK)
        except (BlockingIOError, InterruptedError):
            return False
        except OSError as exc:
            raise SerialException(f"read failed: {exc}") from exc
        if not data:
            raise SerialException("socket disconnected")
        self._held += data
        return True
