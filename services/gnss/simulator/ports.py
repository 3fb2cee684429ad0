"""A receiver's serial ports: what each one takes (INTERFACEMODE), at what rate, and what it
loses when a host sends faster than the line carries.

A TCP connection delivers a host's bytes at once; a serial line carries `baud / 10` bytes a
second (8N1: a start bit, 8 data bits, a stop bit). `Line` puts the bytes a port receives
back on that clock: each arrives when the line has carried it, and what does not fit in the
host's buffer ahead of the line is lost (`overruns`), as a UART's buffer overflows.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from viena.common.twin.serial_port import ByteTwin
from viena.services.gnss.driver.novatel.enums import ComPort, InterfaceMode, Port

from .rtcm_in import RtcmInput

BITS_PER_BYTE = 10                  # 8N1
#: What a host has queued for the line at most (a Linux tty's transmit buffer is 4 KiB).
LINE_BUFFER_BYTES = 4096
FACTORY_BAUD = 9600
#: What a port takes by its receive mode: commands, or corrections this twin reads.
COMMAND_MODES = (InterfaceMode.NOVATEL, InterfaceMode.NOVATELBINARY)


class Line:
    """The bytes a port receives, each at the time the line has carried it."""

    def __init__(self, buffer_bytes: int = LINE_BUFFER_BYTES):
        self.buffer_bytes = buffer_bytes
        self._queue: deque[list] = deque()      # [start_s, bytes, taken, s per byte]: a chunk on the line
        self._busy_until = -math.inf
        self.overruns = 0                       # bytes lost: more than the line carries
        self.carried = 0                        # bytes that crossed it

    def clear(self) -> None:
        self._queue.clear()
        self._busy_until = -math.inf

    def send(self, data: bytes, now_s: float, baud: int) -> None:
        """A host writes `data` at `now_s`: what fits behind the bytes still queued goes on."""
        per_byte = BITS_PER_BYTE / baud
        start = max(now_s, self._busy_until)
        queued = int(round((start - now_s) / per_byte))
        room = max(0, self.buffer_bytes - queued)
        if len(data) > room:
            self.overruns += len(data) - room
            data = data[:room]
        if data:
            self._queue.append([start, bytes(data), 0, per_byte])
            self._busy_until = start + len(data) * per_byte

    def receive(self, now_s: float) -> bytes:
        """The bytes whose last bit has crossed the line by `now_s`."""
        out = bytearray()
        while self._queue:
            chunk = self._queue[0]
            start, data, taken, per_byte = chunk
            done = min(len(data), int(math.floor((now_s - start) / per_byte + 1e-9)))
            if done > taken:
                out += data[taken:done]
                chunk[2] = done
            if done < len(data):
                break
            self._queue.popleft()
        self.carried += len(out)
        return bytes(out)

    def idle_s(self) -> float | None:
        """When what is on the line has crossed it (None: nothing on it). A host writes whole
        frames, so that is when the last frame written is there to read."""
        return self._busy_until if self._queue else None


@dataclass
class ReceiverPort:
    """One serial port of the receiver: its settings (COM, INTERFACEMODE) and its buffers."""

    com: ComPort
    address: Port                       # the header's port address of what it sends
    baud: int = FACTORY_BAUD
    rxtype: InterfaceMode = InterfaceMode.NOVATEL
    txtype: InterfaceMode = InterfaceMode.NOVATEL
    responses: bool = True
    rx: bytearray = field(default_factory=bytearray)
    out: bytearray = field(default_factory=bytearray)
    line: Line = field(default_factory=Line)
    rtcm: RtcmInput = field(default_factory=RtcmInput)

    @property
    def takes_commands(self) -> bool:
        return self.rxtype in COMMAND_MODES

    @property
    def name(self) -> str:
        return ComPort(self.com).name

    def break_(self) -> None:
        """A double break (COM §2.6.10): factory rate, buffers cleared, NOVATEL NOVATEL."""
        self.baud = FACTORY_BAUD
        self.rxtype = self.txtype = InterfaceMode.NOVATEL
        self.responses = True
        self.rx.clear()
        self.out.clear()
        self.line.clear()
        self.rtcm.clear()


class PortTwin(ByteTwin):
    """Another port of a receiver twin, as a ByteTwin of its own: the sim serves it on its
    own endpoint, like the second cable to the receiver (``twin.port("COM2")``). Opening it
    changes nothing at the receiver (no break goes down a corrections cable)."""

    def __init__(self, receiver, com: ComPort):
        self.receiver = receiver
        self.com = com

    def on_connect(self, now_s: float) -> None:
        self.receiver.port_connect(self.com, now_s)

    def feed(self, data: bytes, now_s: float) -> None:
        self.receiver.port_feed(self.com, data, now_s)

    def poll(self, now_s: float) -> bytes:
        return self.receiver.port_poll(self.com, now_s)

    def next_due(self, now_s: float) -> float:
        return self.receiver.port_next_due(self.com, now_s)
