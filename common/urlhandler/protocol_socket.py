"""A `socket://` port that reads what the socket holds in one go and writes without asking first.

python-can's slcan interface asks a port's `in_waiting`, then reads one byte at a time.
pyserial's own socket port answers each of those with a select(), and each byte with a
recv() as well: three system calls a byte, some 18,000 a second for the simulated
drive's CAN traffic, a tenth of a core. This port keeps what one recv() brings and serves
reads and `in_waiting` from it, asking the socket only when it is empty; a write is one
send(), waiting for the socket (select) only if the kernel took less than all of it
(pyserial's selects after every send). URL, open and close are pyserial's. Only the
simulated car needs it: on the car the steering talks socketcan.
"""
from __future__ import annotations

import select

from serial.serialutil import PortNotOpenError, SerialException, SerialTimeoutException, Timeout
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
        """What is held, or (nothing held) what the socket has now: a lower bound, as
        pyserial's own socket port answers 1 for readable."""
        if not self._held:
            self._receive_now()
        return len(self._held)

    def read(self, size: int = 1) -> bytes:
        timeout = Timeout(self._timeout)
        while len(self._held) < size and self._receive(timeout.time_left()) and not timeout.expired():
            pass
        data = bytes(self._held[:size])
        del self._held[:size]
        return data

    def write(self, data) -> int:
        """All of `data` (pyserial's contract), within the write timeout; one send() when
        the socket takes it at once."""
        if not self.is_open:
            raise PortNotOpenError()
        view = memoryview(bytes(data))
        timeout = Timeout(self._write_timeout)
        while view:
            try:
                view = view[self._socket.send(view):]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError as exc:
                raise SerialException(f"write failed: {exc}") from exc
            if not view:
                break
            if timeout.is_non_blocking:
                break
            if timeout.expired():
                raise SerialTimeoutException("Write timeout")
            _, ready, _ = select.select([], [self._socket], [], timeout.time_left())
            if not ready:
                raise SerialTimeoutException("Write timeout")
        return len(data) - len(view)

    def reset_input_buffer(self) -> None:
        self._held.clear()
        super().reset_input_buffer()

    def _receive(self, wait: float | None) -> bool:
        """Add what arrives within `wait` s (None: until something does); False if nothing."""
        if not self.is_open:
            raise PortNotOpenError()
        ready, _, _ = select.select([self._socket], [], [], wait)
        return bool(ready) and self._receive_now()

    def _receive_now(self) -> bool:
        """Add what the socket holds now (one recv(), no waiting); False if nothing."""
        if not self.is_open:
            raise PortNotOpenError()
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
