"""The recorder: every sample of some key expressions, stamped on arrival and written by one
thread, so a slow disk delays the file, not the dataflow.

Used by `viena record` (a tool a person starts) and by the black box (a service that
records every drive); what it writes into is a SampleWriter: one recording
(recording.RecordingWriter), a drive of split files (drive_files.DriveWriter) or a
Foxglove file (viena/foxglove_export.py).
"""
from __future__ import annotations

import logging
from collections import deque
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
#: what zenoh keeps for a batched recorder whose writer is behind (a disk that stalls):
#: some 50 s of the sim car; beyond that the oldest go, and the car never waits
RING_SAMPLES = 20_000


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


class RingSubscribers:
    """Samples kept by zenoh itself (a RingChannel per subscriber: zenoh's thread never waits
    on Python, and would drop the oldest only after RING_SAMPLES behind), taken by the
    writing thread a batch at a time: no Python thread woken once a sample, which was a
    third of the black box's CPU.

    The log time is still when each sample arrived, not when its batch was taken: the
    router stamps every sample it routes (its HLC, zenoh's `timestamping`), so a sample's
    age is the wall clock now less that stamp, and its arrival the receive clock now less
    its age. Each is clamped between the last batch's end and now (a stamp from another
    clock); a sample with no stamp takes the time of the one before it in its ring. The
    rings' samples are then merged by that time (stably: a ring's own order stays), and
    made never to go back, so log times only grow across every key expression.
    """

    def __init__(self, stamp: ReceiveClock | None = None, samples: int | None = None):
        self.stamp = stamp or ReceiveClock()
        self.samples = samples or RING_SAMPLES       # each ring's size
        self._last = self.stamp()
        self._said_unstamped = self._said_closed = False

    def declare(self, session, keyexprs: list[str]) -> list:
        """A subscriber per key expression, each with a ring of `samples`."""
        import zenoh

        return [session.declare_subscriber(k, zenoh.handlers.RingChannel(self.samples)) for k in keyexprs]

    def take(self, subscribers: list, keep: Callable[[str, str], bool] | None = None,
             ) -> tuple[list[tuple[int, str, str, bytes]], list[int]]:
        """Every sample waiting, as (log time, key, encoding, payload) in log time order, and
        how many each ring gave (one that gave `samples` or more may have dropped some).
        `subscribers`: the subscribers, or their handlers; `keep(key, encoding)`: False for a
        sample nobody wants (its payload is then not even copied)."""
        from zenoh import ZError

        now, wall = self.stamp(), clock.time_ns()
        since = self._last
        rings: list[list[tuple[int, str, str, bytes]]] = []
        unstamped = 0
        for sub in subscribers:
            ring: list[tuple[int, str, str, bytes]] = []
            rings.append(ring)
            at = since
            try:
                while (sample := sub.try_recv()) is not None:
                    stamped = sample.timestamp
                    if stamped is not None:
                        at = max(since, min(now, now - wall + stamped.get_time_as_ntp64().as_nanos()))
                    else:
                        unstamped += 1
                    key, encoding = str(sample.key_expr), str(sample.encoding)
                    if keep is None or keep(key, encoding):
                        ring.append((at, key, encoding, sample.payload.to_bytes()))
            except ZError as exc:           # the subscriber or its session is gone: keep what came
                if not self._said_closed:
                    self._said_closed = True
                    log.warning("a subscriber's ring cannot be read (%s): its samples are no longer taken", exc)
        counts = [len(ring) for ring in rings]
        total = sum(counts)
        if total and unstamped == total and not self._said_unstamped:
            self._said_unstamped = True
            log.warning("%d samples came without a zenoh timestamp: logged at the batch before's time, not "
                        "their arrival (is `timestamping` on in the router?)", total)
        taken = rings[0] if len(rings) == 1 else sorted((s for ring in rings for s in ring), key=_log_time)
        last, grown = since, []
        for at, key, encoding, data in taken:
            last = max(last, at)
            grown.append((last, key, encoding, data))
        self._last = now
        return grown, counts


def _log_time(taken: tuple) -> int:
    return taken[0]


class Recorder:
    """Subscribes to key expressions and writes every sample to a SampleWriter.

    `start()` declares the subscribers (unless `listen()` did already: samples queue from
    then on, while a writer is still being made, such as the black box's, which repairs
    the last run's file first) and starts writing; `stop()` writes every sample heard
    until then (batched: those still in zenoh's rings too), undeclares them and closes
    the file. A write error (disk full, a card gone read-only) stops the writing: `error`
    then holds it, `failed` is set and `on_error(exc)` is called once, from the
    writing thread; the subscribers stay, their samples are dropped. `on_sample()` is
    called for every sample heard (a silence warning's `heard`).

    How samples come in: a callback on zenoh's thread stamps each on arrival (any session,
    the simulation's memory bus too); `batched=True` (the black box, on a real zenoh
    session) leaves them in zenoh's own ring (RingSubscribers), taken a batch at a time by the
    writing thread, with no Python run per sample until then.
    """

    def __init__(self, session, keyexprs: list[str], writer: SampleWriter, *,
                 on_sample: Callable[[], None] | None = None,
                 on_error: Callable[[OSError], None] | None = None,
                 batched: bool = False):
        self.session, self.keyexprs, self.writer = session, keyexprs, writer
        self.on_sample, self.on_error = on_sample, on_error
        self.clock = ReceiveClock()
        self.error: OSError | None = None
        self.failed = clock.Event()
        self._arrived: deque = deque()     # (log time, key, encoding, payload): zenoh's threads append
        self._rings = RingSubscribers(self.clock) if batched else None
        #: takes in which a ring gave RING_SAMPLES or more: zenoh may have dropped its oldest
        self.possibly_dropped = 0
        self._largest_batch = 0
        self._stopping = clock.Event()
        self._subscribers: list[zenoh.Subscriber] = []
        self._thread = clock.Thread(target=self._write_loop, name="record-writer", daemon=True)

    def start(self) -> None:
        self.listen()
        self._thread.start()

    def listen(self) -> None:
        """Declare the subscribers: from now on every sample is kept for the writer."""
        if self._subscribers:
            return
        if self._rings is not None:
            self._subscribers = self._rings.declare(self.session, self.keyexprs)
            return
        stamp, append, heard = self.clock, self._arrived.append, self.on_sample

        def on_sample(sample) -> None:      # zenoh's thread: stamp and keep, nothing else
            append((stamp(), str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes()))
            if heard is not None:
                heard()

        for keyexpr in self.keyexprs:
            self._subscribers.append(self.session.declare_subscriber(keyexpr, on_sample))

    @property
    def samples(self) -> int:
        return self.writer.samples

    def backlog(self) -> int:
        """How far behind the writer is: the samples heard and not yet written, or, batched
        (what zenoh's rings hold is not known until taken), the largest batch taken since
        the last call."""
        largest, self._largest_batch = self._largest_batch, 0
        return max(len(self._arrived), largest)

    def _write_loop(self) -> None:
        """Write what arrived, a batch every BATCH_S, so the thread wakes some 20 times a
        second rather than once a sample (the wake-ups were most of the recorder's CPU).
        Every FLUSH_PERIOD_S it closes the chunk and makes it durable, so a recorder killed
        (or a car switched off) loses at most that much. After `stop()`: what is left, then out."""
        flush_at = clock.monotonic() + FLUSH_PERIOD_S
        while True:
            stopping = self._stopping.wait(BATCH_S)
            self._write(self._taken())
            if stopping:
                return
            if clock.monotonic() >= flush_at:
                flush_at = clock.monotonic() + FLUSH_PERIOD_S
                self._flush()

    def _taken(self) -> list:
        """What arrived so far, oldest first (zenoh's threads go on adding meanwhile)."""
        if self._rings is not None:
            rung, counts = self._rings.take(self._subscribers)
            self._largest_batch = max(self._largest_batch, len(rung))
            full = sum(n >= self._rings.samples for n in counts)
            if full:
                self.possibly_dropped += full
                log.warning("the writer fell %d samples behind: zenoh's ring (%d) may have dropped the oldest",
                            max(counts), self._rings.samples)
            if rung and self.on_sample is not None:
                self.on_sample()                 # heard (a silence warning's flag): once a batch will do
            return rung
        arrived = self._arrived
        return [arrived.popleft() for _ in range(len(arrived))]

    def _write(self, batch: list) -> None:
        """Write a batch (after an error: drop it)."""
        if self.error is not None:
            return
        write = self.writer.write
        for log_time, key, encoding, data in batch:
            try:
                write(key, encoding, log_time, data)
            except OSError as exc:
                self._failed(exc)                # nothing more goes to a broken file
                return

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
        """Write every sample heard until now, stop listening, close. The final path, or None
        if the file could not be completed (it stays as `.part`).

        Batched, the writing thread stops first, taking what is left in zenoh's rings, and
        the subscribers go after (undeclaring one deletes its ring); with callbacks, the
        subscribers go first, so nothing is appended after the thread's last take."""
        if self._rings is not None:
            self._stopping.set()
            self._thread.join()
            self.unlisten()
        else:
            self.unlisten()
            self._stopping.set()
            self._thread.join()
        if self.error is None:
            try:
                return self.writer.close()
            except OSError as exc:
                self._failed(exc)
        self.writer.abandon()
        return None
