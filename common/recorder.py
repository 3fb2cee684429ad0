"""The recorder: every sample of some key expressions, stamped on arrival and written by one
thread, so a slow disk delays the file, not the dataflow.

Used by `viena record` (a tool a person starts) and by the black box (a service that
records every drive); what it writes into is a SampleWriter: one recording
(recording.RecordingWriter), a drive of split files (drive_files.DriveWriter) or a
Foxglove file (viena/foxglove_export.py).
"""
from __future__ import annotations

import logging
import queue
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from viena.common import clock
from viena.common.recording import ReceiveClock

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("viena.recorder")
#: chunks are closed and made durable this often: what a kill -9 or a power cut can lose
FLUSH_PERIOD_S = 0.5
#: the writing thread takes the samples this often, all that came at once
BATCH_S = 0.05


class SampleWriter(Protocol):
    """What the recorder writes into: a recording of zenoh samples (RecordingWriter), a
    drive of split files (DriveWriter) or Foxglove channels (FoxgloveWriter)."""

    @property
    def part(self) -> Path: ...

    @property
    def samples(self) -> int: ...

    @property
    def keys(self) -> int: ...

    @property
    def size(self) -> int: ...

    def write(self, key: str, encoding: str, log_time: int, data: bytes) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> Path: ...

    def abandon(self) -> None: ...

    def discard(self) -> None: ...


class Recorder:
    """Subscribes to key expressions and writes every sample to a SampleWriter.

    `start()` declares the subscribers (unless `listen()` did already: samples queue from
    then on, while a writer is still being made, such as the black box's, which repairs
    the last run's file first) and starts writing; `stop()` undeclares them, writes what
    is queued and closes the file. A write error (disk full, a card gone read-only) stops the writing:
    `error` then holds it, `failed` is set and `on_error(exc)` is called once, from the
    writing thread; the subscribers stay, their samples are dropped. `on_sample()` is
    called from zenoh's threads for every sample heard (a silence warning's `heard`).
    """

    def __init__(self, session, keyexprs: list[str], writer: SampleWriter, *,
                 on_sample: Callable[[], None] | None = None,
                 on_error: Callable[[OSError], None] | None = None):
        self.session, self.keyexprs, self.writer = session, keyexprs, writer
        self.on_sample, self.on_error = on_sample, on_error
        self.clock = ReceiveClock()
        self.error: OSError | None = None
        self.failed = clock.Event()
        self._queue = clock.Queue()
        self._subscribers: list[zenoh.Subscriber] = []
        self._thread = clock.Thread(target=self._write_loop, name="record-writer", daemon=True)

    def start(self) -> None:
        self.listen()
        self._thread.start()

    def listen(self) -> None:
        """Declare the subscribers: from now on every sample is queued for the writer."""
        if self._subscribers:
            return
        stamp, put, heard = self.clock, self._queue.put, self.on_sample

        def on_sample(sample) -> None:      # zenoh's thread: stamp and queue, nothing else
            put((stamp(), str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes()))
            if heard is not None:
                heard()

        for keyexpr in self.keyexprs:
            self._subscribers.append(self.session.declare_subscriber(keyexpr, on_sample))

    @property
    def samples(self) -> int:
        return self.writer.samples

    def backlog(self) -> int:
        return self._queue.qsize()

    def _write_loop(self) -> None:
        """Write what arrives, a batch at a time: woken by the first sample, the thread lets
        BATCH_S pass and then writes everything queued, so it wakes some 20 times a second
        rather than once a sample (the wake-ups were most of the recorder's CPU). Every
        FLUSH_PERIOD_S it closes the chunk and makes it durable, so a recorder killed (or a
        car switched off) loses at most that much."""
        get = self._queue.get
        flush_at = clock.monotonic() + FLUSH_PERIOD_S
        while True:
            try:
                first = get(timeout=max(0.0, flush_at - clock.monotonic()))
            except queue.Empty:
                first = ()
            batch = [first]
            if first is not None and first:
                clock.sleep(BATCH_S)
                batch += self._queued()
            if not self._write(batch):
                return
            if clock.monotonic() >= flush_at:
                flush_at = clock.monotonic() + FLUSH_PERIOD_S
                self._flush()

    def _queued(self) -> list:
        items = []
        while True:
            try:
                items.append(self._queue.get(block=False))
            except queue.Empty:
                return items

    def _write(self, batch: list) -> bool:
        """Write a batch (after an error: drop it); False once the stop (None) is in it."""
        write = self.writer.write
        for item in batch:
            if item is None:
                return False
            if item and self.error is None:
                log_time, key, encoding, data = item
                try:
                    write(key, encoding, log_time, data)
                except OSError as exc:
                    self._failed(exc)            # drain: nothing more goes to a broken file
        return True

    def _flush(self) -> None:
        if self.error is None:
            try:
                self.writer.flush()
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        self.error = exc
        self.failed.set()
        if self.on_error is not None:
            try:
                self.on_error(exc)
            except Exception:
                log.exception("the recorder's on_error failed")

    def unlisten(self) -> None:
        """Undeclare the subscribers (nothing more is queued)."""
        for sub in self._subscribers:
            try:
                sub.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        self._subscribers.clear()

    def stop(self) -> Path | None:
        """Stop listening, write the backlog, close. The final path, or None if the
        file could not be completed (it stays as `.part`)."""
        self.unlisten()
        self._queue.put(None)
        self._thread.join()
        if self.error is None:
            try:
                return self.writer.close()
            except OSError as exc:
                self._failed(exc)
        self.writer.abandon()
        return None
