"""What both Razor drivers share: open a link (any pyserial URL), decode its chunks, stamp
and number frames. Reading is pulled: `read()` waits on the link in the caller's thread."""
from __future__ import annotations

import time
from collections import deque
from typing import Iterator, NamedTuple

from viena.common.link import SerialLink
from viena.services.imu.driver.frames import Frame
from viena.services.imu.driver.timing import CadenceClock


class Reading(NamedTuple):
    """One frame as the host received it."""

    t_ns: int          # estimated acquisition time, ns UTC (see timing.CadenceClock)
    t_host_ns: int     # when the host read the chunk holding the frame, ns UTC
    seq: int           # host frame counter: jumps by the number of frame slots lost
    frame: Frame


class SerialImu:
    """Base of the drivers: subclasses say how bytes become frames (`_decode`)."""

    firmware = ""
    BAUDRATE = 0
    RATE_HZ = 0.0

    def __init__(self, url: str, baudrate: int | None = None, *, timeout: float = 0.1,
                 rate_hz: float | None = None):
        self.url = url
        self.timeout = timeout
        self.link = SerialLink(url, baudrate or self.BAUDRATE)
        self.clock = CadenceClock(1.0 / (rate_hz or self.RATE_HZ))
        self._pending: deque[Reading] = deque()
        self._received = 0          # stream offset: bytes received since open
        self._last_slot: float | None = None
        self._seq = -1

    # -- opening and closing -------------------------------------------------------------
    def open(self) -> "SerialImu":
        """Open the port and get the stream going; raises serial.SerialException (OSError)."""
        self.link.open()
        self._received = 0
        self._last_slot = None
        self._pending.clear()
        self.clock.reset()
        try:
            self._start_stream()
        except Exception:
            self.link.close()
            raise
        return self

    def close(self) -> None:
        self.link.close()

    @property
    def is_open(self) -> bool:
        return self.link.is_open

    def __enter__(self):
        if not self.is_open:
            self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- reading -------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> Reading | None:
        """The next frame, waiting up to `timeout` s (default: the driver's `timeout`);
        None if none came. Raises serial.SerialException when the device is gone."""
        if not self._pending:
            wait = self.timeout if timeout is None else timeout
            deadline = time.monotonic() + wait
            while not self._pending:
                left_s = deadline - time.monotonic()
                data, t_host = self.link.read(max(0.0, min(left_s, self.timeout)))
                if data:
                    self._ingest(data, t_host)
                elif left_s <= 0:
                    return None
        return self._pending.popleft()

    def __iter__(self) -> Iterator[Reading]:
        """Frames until the port is closed (a shell's `for r in imu: print(r)`)."""
        while self.is_open:
            reading = self.read()
            if reading is not None:
                yield reading

    def _ingest(self, data: bytes, t_host_ns: int) -> None:
        self._received += len(data)
        byte_ns = self.link.byte_time_s * 1e9
        for slot, offset, frame in self._decode(data):
            step = 1 if self._last_slot is None else max(1, round(slot - self._last_slot))
            self._last_slot = slot
            self._seq += step
            arrival = t_host_ns - int((self._received - offset) * byte_ns)
            self._pending.append(Reading(self.clock.stamp(arrival, step), t_host_ns, self._seq, frame))

    # -- for subclasses ------------------------------------------------------------------
    def _start_stream(self) -> None:
        """Whatever the firmware needs after the port opens."""

    def _decode(self, data: bytes) -> list[tuple[float, int, Frame]]:
        """(frame slot position, stream offset of the frame's first byte, frame) for each
        frame completed by `data`; the slot position counts frame periods since open."""
        raise NotImplementedError
