"""Corrections to a receiver's port on a thread of their own: `put()` never blocks (a zenoh
callback calls it), the thread runs the feed's rules (feed.py) and writes, so neither a slow
line nor a caster's flood ever holds up the log reading or the subscriber.

The port is the logs' own (the receiver's `write_corrections`, under the link's write lock,
so a command's frame never lands inside a correction frame) or a second serial URL
(`SecondPort`, reopened after a failure). Until `attach()` names one, the receiver is not
ready (starting, refused, reconnecting) and what comes is dropped, counted.

Only the writer's thread touches the feed (its framer's buffer above all): `attach()`, on
the supervisor's thread, marks a new target and the thread resets the framer at its next
step; a write in progress finishes before `attach()` returns, so nothing lands on a port
being set up. A step that raises anything is logged (with its traceback, at most every
ERROR_LOG_S), its bytes counted as dropped "internal", and the thread goes on.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import serial

from viena.common import clock
from viena.common.link import open_link

from .feed import CorrectionsFeed, Taken

log = logging.getLogger(__name__)

WRITE_ERRORS = (serial.SerialException, OSError)
#: a second port that failed is tried again after this long
REOPEN_S = 1.0
#: how often the thread wakes without input (the caller's `on_tick`: ages in health)
TICK_S = 0.5
#: a writer step that keeps failing is logged with its traceback at most this often
ERROR_LOG_S = 60.0


class SecondPort:
    """The receiver's other serial port (its COM2), written to only."""

    def __init__(self, url: str, baud: int):
        self.url, self.baud = url, baud
        self._link = open_link(url, baud)
        self._failed_at: float | None = None

    def write(self, data: bytes) -> None:
        """Write, opening the port first if needed; a port that failed is left alone for
        REOPEN_S (its bytes raise as the failure did)."""
        if not self._link.is_open:
            now = clock.monotonic()
            if self._failed_at is not None and now - self._failed_at < REOPEN_S:
                raise serial.SerialException(f"{self.url}: not open (failed {now - self._failed_at:.1f} s ago)")
            try:
                self._link.open(self.baud)
            except WRITE_ERRORS:
                self._failed_at = now
                raise
        try:
            self._link.write(data)
        except WRITE_ERRORS:
            self._failed_at = clock.monotonic()
            self._link.close()
            raise

    def close(self) -> None:
        self._link.close()


class CorrectionsWriter:
    """The thread between the subscriber and the port. `on_taken(taken)` and
    `on_port_error(exc)` are called from it after each sample, `on_tick()` every TICK_S."""

    def __init__(self, feed: CorrectionsFeed, *, queue_size: int = 64,
                 on_taken: Callable[[Taken], None] | None = None,
                 on_port_error: Callable[[Exception], None] | None = None,
                 on_tick: Callable[[], None] | None = None, name: str = "corrections"):
        self.feed = feed
        self._queue = clock.Queue(maxsize=queue_size)
        self._write: Callable[[bytes], None] | None = None
        #: the target changed: the framer's partial frame goes at the thread's next step
        self._reset_pending = False
        #: held over a step's write: attach() waits for a write in progress
        self._lock = threading.Lock()
        #: steps (or ticks) that raised; the last time one was logged
        self.internal_errors = 0
        self._error_logged_s: float | None = None
        self._errors_quiet = 0
        #: bytes dropped because the queue was full (counted by put()'s thread alone)
        self.queue_dropped_bytes = 0
        self._on_taken, self._on_port_error, self._on_tick = on_taken, on_port_error, on_tick
        self._stopping = clock.Event()
        self._thread = clock.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> CorrectionsWriter:
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def attach(self, write: Callable[[bytes], None] | None) -> None:
        """Where the bytes go from now on; None: the receiver is not ready for them. Waits
        for a write in progress, so none lands on the port after this returns. A frame cut
        across two samples is not finished on another port's start (the writer's thread
        drops it, at its next step: the framer is its own)."""
        with self._lock:
            if write is not self._write:
                self._reset_pending = True
            self._write = write

    @property
    def attached(self) -> bool:
        return self._write is not None

    def put(self, data: bytes, sample_format: str) -> None:
        """Queue a sample's bytes; never blocks (a full queue drops them, counted)."""
        try:
            self._queue.put_nowait((data, sample_format))
        except clock.Full:
            self.queue_dropped_bytes += len(data)

    def _run(self) -> None:
        next_tick = clock.monotonic()
        while not self._stopping.is_set():
            try:
                data, sample_format = self._queue.get(timeout=TICK_S)
            except clock.Empty:
                pass
            else:
                self.step(data, sample_format)
            now = clock.monotonic()
            if self._on_tick is not None and now >= next_tick:
                next_tick = now + TICK_S
                try:
                    self._on_tick()
                except Exception as exc:  # noqa: BLE001 - the thread must outlive a bad report
                    self._internal_error("tick", exc)

    def step(self, data: bytes, sample_format: str) -> Taken | None:
        """`write_now`, and whatever it raises logged and its bytes counted as dropped
        "internal": one bad step never ends the thread (the corrections would stop for good)."""
        counts = self.feed.counts
        samples_before = counts.samples
        try:
            return self.write_now(data, sample_format)
        except Exception as exc:  # noqa: BLE001 - see the docstring
            if counts.samples == samples_before:        # it failed before the feed counted it
                counts.samples += 1
                counts.bytes_in += len(data)
            self.feed.splitter.reset()                  # it may be half way through: its bytes are lost too
            self.feed.drop("internal", self.feed.unaccounted())
            self._internal_error("step", exc)
            return None

    def write_now(self, data: bytes, sample_format: str) -> Taken | None:
        """One sample through the feed to the port (the thread's step; tests call it)."""
        with self._lock:
            if self._reset_pending:
                self._reset_pending = False
                self.feed.restart()
            write = self._write
            if write is None:
                self.feed.counts.samples += 1
                self.feed.counts.bytes_in += len(data)
                self.feed.drop("not_ready", len(data))
                return None
            taken = self.feed.take(data, sample_format, clock.monotonic())
            failure: Exception | None = None
            if taken.data:
                try:
                    write(taken.data)
                except WRITE_ERRORS as exc:
                    self.feed.drop("port", len(taken.data))
                    failure = exc
                else:
                    self.feed.wrote(taken)
        if failure is not None and self._on_port_error is not None:
            self._on_port_error(failure)
        if self._on_taken is not None:
            self._on_taken(taken)
        return taken

    def _internal_error(self, where: str, exc: Exception) -> None:
        """A bug, not the port: its traceback once, then at most every ERROR_LOG_S."""
        self.internal_errors += 1
        now = clock.monotonic()
        if self._error_logged_s is not None and now - self._error_logged_s < ERROR_LOG_S:
            self._errors_quiet += 1
            return
        more = f" [{self._errors_quiet} more since the last]" if self._errors_quiet else ""
        self._error_logged_s, self._errors_quiet = now, 0
        log.error("%s: corrections writer %s failed: %r%s", self._thread.name, where, exc, more, exc_info=exc)
