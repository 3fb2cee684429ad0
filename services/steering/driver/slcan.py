"""python-can's `slcan` bus, cheaper on the steering's traffic: reads in bulk, writes a
control period's frames at once.

python-can's slcanBus reads the adapter one byte per call (`read(1)`, ~20 a frame) and
writes each frame on its own. The steering hears some 400 lines a second from its adapter
(two TPDOs per SYNC, the drive's heartbeat, and the adapter's acknowledgement of every
frame sent) and sends two or three frames every SYNC period: per byte and per frame
Python calls and system calls were most of the service's CPU on the simulated drive.
Here a read takes what the port holds in one call and serves lines from it, standard
data frames are parsed at once and the acknowledgements skipped without leaving the bus;
`send_frames` puts several frames in one write (one system call; the adapter's
acknowledgements, one per frame, then come back together). The protocol is python-can's:
lines, commands and parsing are unchanged.
"""
from __future__ import annotations

import functools
import logging
from collections.abc import Iterable

import can
import serial
from can.interfaces.slcan import error_check, slcanBus

from viena.common import clock

log = logging.getLogger(__name__)

#: what an adapter answers to a frame it sent (CR; CANable and LAWICEL: z, Z)
_ACKS = frozenset({"\r", "z\r", "Z\r"})
_DLCS = frozenset("012345678")


class SlcanBus(slcanBus):
    """An slcan adapter (serial port, or `socket://` for the twin's hub)."""

    def _read(self, timeout: float | None) -> str | None:
        """The next line (with its terminator), from what was read before or from one read
        of all the port holds; None if none is complete within `timeout`."""
        held = self._buffer
        end = _line_end(held)
        if end < 0:
            deadline = serial.Timeout(timeout)
            port = self.serialPortOrig
            with error_check("Could not read from serial device"):
                while end < 0:
                    chunk = port.read(1)                      # waits up to the port's timeout
                    if chunk:
                        held += chunk
                        waiting = port.in_waiting
                        if waiting:
                            held += port.read(waiting)
                        end = _line_end(held)
                    if end < 0 and deadline.expired():     # (a port that streams without a CR too)
                        return None
        line = held[:end + 1].decode("ascii", "replace")    # a garbled byte spoils its line, not the bus
        del held[:end + 1]
        return line

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        """The next frame: a standard data frame parsed here, the adapter's acknowledgements
        of our own frames skipped here, anything else parsed by python-can."""
        if self._queue.qsize():
            return super()._recv_internal(timeout)
        deadline = serial.Timeout(timeout)
        while True:
            line = self._read(deadline.time_left())
            if line is None:
                return None, False
            if line in _ACKS:
                continue
            try:
                if line[0] == "t" and len(line) >= 6 and line[4] in _DLCS:    # python-can's parse, without
                    dlc = int(line[4])                                      # its queue: ~1 % of a core at 50 Hz
                    return can.Message(arbitration_id=int(line[1:4], 16), is_extended_id=False,
                                       timestamp=clock.time(), dlc=dlc,
                                       data=bytearray.fromhex(line[5:5 + 2 * dlc])), False
                self._queue.put_nowait(line)                # anything else: python-can parses it
                return super()._recv_internal(0)
            except (ValueError, IndexError):                # a garbled line spoils itself, not the bus
                log.debug("slcan line not understood: %r", line)

    def send_frames(self, frames: Iterable[tuple[int, bytes]]) -> None:
        """Send these standard data frames (id, data), in order, with one write."""
        self._write("\r".join([_line(can_id, payload) for can_id, payload in frames]))   # it ends the last


@functools.lru_cache(maxsize=256)
def _line(can_id: int, payload: bytes) -> str:
    """A standard data frame's slcan line, without its CR: the period's frames repeat (SYNC,
    heartbeat, an RPDO holding its target), so each is formatted once."""
    return f"t{can_id:03X}{len(payload)}{payload.hex().upper()}"


def _line_end(held: bytearray) -> int:
    """Index of the first line's terminator (CR, or BEL for an error), or -1."""
    end = held.find(b"\r")
    if b"\a" in held:
        bel = held.find(b"\a")
        return bel if end < 0 or bel < end else end
    return end
