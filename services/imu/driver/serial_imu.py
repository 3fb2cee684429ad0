"""What both Razor drivers share: open a link (any URL `open_link` takes), decode its
chunks, stamp and number frames. Reading is pulled: `read()` waits on the link in the
caller's thread.

A decoder may hold a complete frame until the bytes after it confirm it (the next frame's
start); when none come, the line falling silent for a frame time confirms it instead, so
`read()` waits for that silence at most (`silence_s`, one frame's time on the wire) before
it hands the frame on.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import NamedTuple

from viena.common import clock
from viena.common.link import open_link
from viena.services.imu.driver.frames import Frame
from viena.services.imu.driver.timing import CadenceClock


class Reading(NamedTuple):
    """One frame as the host received it."""

    t_ns: int          # estimated acquisition time, ns UTC (see timing.CadenceClock)
    t_host_ns: int     # when the host read the chunk holding the frame's last byte, ns UTC
    seq: int           # host frame counter: jumps by the number of frame slots lost
    frame: Frame


class SerialImu:
    """Base of the drivers: subclasses say how bytes become frames (`_decode`, and
    `_decode_silence` when their decoder waits for what follows a frame)."""

    firmware = ""
    BAUDRATE = 0
    RATE_HZ = 0.0
    FRAME_BYTES = 0             # one frame on the wire: what "silent for a frame time" means

    def __init__(self, url: str, baudrate: int | None = None, *, timeout: float = 0.1,
                 rate_hz: float | None = None, silence_s: float | None = None):
        self.url = url
        self.timeout = timeout
        self.link = open_link(url, baudrate or self.BAUDRATE)
        self.silence_s = (self.FRAME_BYTES * self.link.byte_time_s if silence_s is None
                          else silence_s)
        self.clock = CadenceClock(1.0 / (rate_hz or self.RATE_HZ))
        self._pending: deque[Reading] = deque()
        #: recent chunks as (stream offset just after, t_host_ns), to time frames confirmed late
        self._chunks: deque[tuple[int, int]] = deque(maxlen=256)
        self._received = 0          # stream offset: bytes received since open
        self._last_bytes_ns = 0     # monotonic time of the last chunk
        self._last_slot: float | None = None
        self._seq = -1

    # -- opening and closing -------------------------------------------------------------
    def open(self) -> SerialImu:
        """Open the port and get the stream going; raises serial.SerialException (OSError)."""
        self.link.open()
        self._received = 0
        self._chunks.clear()
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
        wait = self.timeout if timeout is None else timeout
        # whole ns: a virtual clock wakes the wait for silence exactly when it has lasted
        deadline_ns = clock.monotonic_ns() + round(wait * 1e9)
        silence_ns = round(self.silence_s * 1e9)
        while not self._pending:
            now_ns = clock.monotonic_ns()
            poll_ns = round(self.timeout * 1e9)
            if self._awaiting_silence():
                quiet_ns = now_ns - self._last_bytes_ns
                if quiet_ns >= silence_ns:
                    self._stamp(self._decode_silence())
                    continue
                poll_ns = silence_ns - quiet_ns
            left_ns = deadline_ns - now_ns
            if left_ns <= 0:
                return None
            data, t_host = self.link.read(min(left_ns, poll_ns) / 1e9)
            if data:
                self._ingest(data, t_host)
        return self._pending.popleft()

    def __iter__(self) -> Iterator[Reading]:
        """Frames until the port is closed (a shell's `for r in imu: print(r)`)."""
        while self.is_open:
            reading = self.read()
            if reading is not None:
                yield reading

    def _ingest(self, data: bytes, t_host_ns: int) -> None:
        self._received += len(data)
        self._last_bytes_ns = clock.monotonic_ns()
        self._chunks.append((self._received, t_host_ns))
        self._stamp(self._decode(data))

    def _stamp(self, decoded: list[tuple[float, int, Frame, int]]) -> None:
        """Number and time the frames: each frame's first byte arrived one frame's line time
        before its last, which came in a chunk read at a known host time."""
        byte_ns = self.link.byte_time_s * 1e9
        chunks = self._chunks
        for slot, offset, frame, end in decoded:
            while len(chunks) > 1 and chunks[0][0] < end:
                chunks.popleft()                    # frames come in order: done with it
            chunk_end, t_host_ns = chunks[0]
            step = 1 if self._last_slot is None else max(1, round(slot - self._last_slot))
            self._last_slot = slot
            self._seq += step
            arrival = t_host_ns - int((chunk_end - offset) * byte_ns)
            self._pending.append(Reading(self.clock.stamp(arrival, step), t_host_ns, self._seq, frame))

    # -- for subclasses ------------------------------------------------------------------
    @property
    def stats(self) -> object:
        """The decoder's counters, as attributes by name (the service reports them as health)."""
        raise NotImplementedError

    def _start_stream(self) -> None:
        """Whatever the firmware needs after the port opens."""

    def _decode(self, data: bytes) -> list[tuple[float, int, Frame, int]]:
        """(frame slot position, stream offset of the frame's first byte, frame, stream
        offset just after its last byte) for each frame `data` completes and confirms; the
        slot position counts frame periods since open."""
        raise NotImplementedError

    def _awaiting_silence(self) -> bool:
        """Whether the decoder holds a complete frame that silence would confirm."""
        return False

    def _decode_silence(self) -> list[tuple[float, int, Frame, int]]:
        """The frames the line's silence confirms (as `_decode`)."""
        return []
