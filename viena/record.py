"""`viena record [KEYEXPR ...] -o drive.mcap`: every sample of the selected keys into an MCAP file.

Keys default to viena/** (viena/NAME/** when --car or the settings name a car). Each
key gets a channel named by its schema; log time is when the sample arrived, publish
time the sample's own `t`. Ctrl-C, SIGTERM or --duration close the file cleanly.
While recording, the file is `drive.mcap.part`; it takes its real name only once it is
complete, so a recording cut short (killed, disk full) never passes for a good one
(`viena replay` and `viena export` still read a `.part` as far as it goes).
Chunks are closed and made durable every FLUSH_PERIOD_S, so a recorder killed (kill -9,
power cut) loses at most that much; `viena record --repair drive.mcap.part` then rewrites
what is there as a complete `drive.mcap` that any MCAP reader opens.

Zenoh's threads only stamp and queue each sample; one thread writes, so a slow disk
delays the file, not the dataflow. Nothing on the keys for a few seconds is said on
stderr; a recording that got nothing at all is not kept, and the exit status is 1.
"""
from __future__ import annotations

import argparse
import logging
import queue
import socket
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from viena.common import clock
from viena.common.recording import ReceiveClock, RecordingError, RecordingWriter, human_bytes, repair
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, SilenceWarning, add_timeout_flag, guarded, key_expressions, tool_logging

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("viena.record")
PROGRESS_PERIOD_S = 0.5
#: chunks are closed and made durable this often: what a kill -9 or a power cut can lose
FLUSH_PERIOD_S = 0.5
#: how often the progress line is printed when stderr is not a terminal (a log file)
LOG_PERIOD_S = 10.0


class SampleWriter(Protocol):
    """What the recorder writes into: a recording of zenoh samples (RecordingWriter) or of
    Foxglove channels (foxglove_export.FoxgloveWriter, `record --foxglove`)."""

    part: Path
    samples: int

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

    `start()` declares the subscribers; `stop()` undeclares them, writes what is queued and
    closes the file. A write error stops the writing; `error` then holds it.
    """

    def __init__(self, session, keyexprs: list[str], writer: SampleWriter):
        self.session, self.keyexprs, self.writer = session, keyexprs, writer
        self.clock = ReceiveClock()
        self.error: OSError | None = None
        self.failed = clock.Event()
        self.silence = SilenceWarning("viena record", keyexprs)
        self._queue = clock.Queue()
        self._subscribers: list[zenoh.Subscriber] = []
        self._thread = clock.Thread(target=self._write_loop, name="record-writer", daemon=True)

    def start(self) -> None:
        self._thread.start()
        stamp, put, heard = self.clock, self._queue.put, self.silence.heard

        def on_sample(sample) -> None:      # zenoh's thread: stamp and queue, nothing else
            put((stamp(), str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes()))
            heard()

        for keyexpr in self.keyexprs:
            self._subscribers.append(self.session.declare_subscriber(keyexpr, on_sample))

    @property
    def samples(self) -> int:
        return self.writer.samples

    def backlog(self) -> int:
        return self._queue.qsize()

    def _write_loop(self) -> None:
        """Write what arrives; every FLUSH_PERIOD_S close the chunk and make it durable, so
        a recorder killed (or a car switched off) loses at most that much."""
        get, write = self._queue.get, self.writer.write
        flush_at = clock.monotonic() + FLUSH_PERIOD_S
        while True:
            try:
                item = get(timeout=max(0.0, flush_at - clock.monotonic()))
            except queue.Empty:
                item = ()
            if item is None:
                return
            try:
                if item and self.error is None:
                    log_time, key, encoding, data = item
                    write(key, encoding, log_time, data)
                if clock.monotonic() >= flush_at:
                    flush_at = clock.monotonic() + FLUSH_PERIOD_S
                    if self.error is None:
                        self.writer.flush()
            except OSError as exc:
                self.error = exc             # drain: nothing more goes to a broken file
                self.failed.set()

    def stop(self) -> Path | None:
        """Stop listening, write the backlog, close. The final path, or None if the
        file could not be completed (it stays as `.part`)."""
        for sub in self._subscribers:
            try:
                sub.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        self._subscribers.clear()
        self._queue.put(None)
        self._thread.join()
        if self.error is None:
            try:
                return self.writer.close()
            except OSError as exc:
                self.error = exc
        self.writer.abandon()
        return None


def default_output() -> str:
    return datetime.fromtimestamp(clock.time(), UTC).strftime("viena-%Y%m%d-%H%M%S.mcap")


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena record", description=__doc__)
    parser.add_argument("keyexprs", nargs="*", metavar="KEYEXPR",
                        help="key expressions to record (default viena/**)")
    parser.add_argument("-o", "--output", metavar="FILE", default=None,
                        help="the MCAP file to write (default viena-<UTC time>.mcap)")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C or SIGTERM)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    parser.add_argument("--foxglove", action="store_true",
                        help="write a recording Foxglove and Lichtblick open (JSON with schemas, map "
                             "and pose channels) instead of viena's msgpack one, which alone replays "
                             "exactly")
    parser.add_argument("--repair", metavar="FILE", default=None,
                        help="record nothing: rewrite FILE, a recording cut short (drive.mcap.part "
                             "after a kill or a power cut), as a complete MCAP file (-o, default "
                             "drive.mcap) with every sample still readable")
    add_timeout_flag(parser)
    add_common_arguments(parser)
    parser._option_string_actions["--car"].help = (
        "record only viena/NAME/** (default: every car, viena/**)")
    return parser


class Progress:
    """One line on stderr: rewritten in place on a terminal, printed now and then in a log."""

    def __init__(self, recorder: Recorder, output: Path, quiet: bool):
        self.recorder, self.output, self.quiet = recorder, output, quiet
        self.tty = sys.stderr.isatty()
        self._t0 = self._t_last = self._t_printed = clock.monotonic()
        self._n_last = 0

    def update(self, final: bool = False) -> None:
        now = clock.monotonic()
        n = self.recorder.samples
        rate = (n - self._n_last) / max(now - self._t_last, 1e-6)
        self._t_last, self._n_last = now, n
        if self.quiet or final:
            return
        line = (f"recording {self.output}: {n} samples, {rate:.0f}/s, "
                f"{human_bytes(self.recorder.writer.size)}")
        if self.tty:
            print(f"\r{line}\033[K", end="", file=sys.stderr, flush=True)
        elif now - self._t_printed >= LOG_PERIOD_S:
            self._t_printed = now
            print(line, file=sys.stderr, flush=True)

    def done(self, path: Path) -> None:
        if self.tty and not self.quiet:
            print("\r\033[K", end="", file=sys.stderr)
        r = self.recorder
        print(f"recorded {r.samples} samples on {r.writer.keys} keys in "
              f"{clock.monotonic() - self._t0:.1f} s into {path} ({human_bytes(path.stat().st_size)})",
              file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    return guarded("viena record", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    if args.repair is not None:
        return _repair(args)
    link = Connection(args)
    keyexprs = key_expressions(args.keyexprs or [link.keys.all if args.car or "car" in link.toml
                                                 else "viena/**"])
    output = Path(args.output or default_output())
    try:
        metadata = {"keyexprs": " ".join(keyexprs), "car": link.car, "host": socket.gethostname(),
                    "started": datetime.fromtimestamp(clock.time(), UTC).isoformat(timespec="seconds")}
        if args.foxglove:
            from viena.foxglove_export import FoxgloveWriter  # the SDK only when asked for
            writer: SampleWriter = FoxgloveWriter(output, metadata=metadata)
        else:
            writer = RecordingWriter(output, metadata=metadata)
    except OSError as exc:
        raise Fail(f"cannot write {output}: {exc.strerror or exc}") from None

    stop = stop_on_signals()
    try:
        session = link.open(stop, args.timeout)
    except Fail:
        writer.discard()
        raise
    if session is None:
        writer.discard()
        raise Fail("stopped before the router answered: nothing recorded")
    recorder = Recorder(session, keyexprs, writer)
    progress = Progress(recorder, output, args.quiet)
    try:
        recorder.start()
        _record_until_stopped(recorder, progress, args.duration, stop)
    finally:
        path = recorder.stop()
        session.close()
    error = recorder.error
    if error is not None or path is None:          # stop() gives no path only with an error
        why = (error.strerror or error) if error is not None else "not completed"
        raise Fail(f"cannot write {output}: {why} (after {recorder.samples} "
                   f"samples; what was written is in {writer.part}, not a complete recording)")
    if recorder.samples == 0:
        path.unlink(missing_ok=True)
        raise Fail(f"nothing came on {', '.join(repr(k) for k in keyexprs)}: no file written (is "
                   f"the key right? `viena list` shows what the car publishes)")
    progress.done(path)
    return 0


def _repair(args: argparse.Namespace) -> int:
    """`--repair FILE`: a new, complete file; the damaged one is left as it was."""
    if args.keyexprs:
        raise Fail("--repair takes a file, not key expressions", status=2)
    try:
        path, samples, lost = repair(args.repair, args.output)
    except RecordingError as exc:
        raise Fail(str(exc), status=2) from None
    except OSError as exc:
        raise Fail(f"cannot repair {args.repair}: {exc.strerror or exc}") from None
    for line in lost:
        print(f"viena record: {args.repair}: {line}", file=sys.stderr)
    print(f"repaired {args.repair} into {path}: {samples} samples ({human_bytes(path.stat().st_size)})",
          file=sys.stderr, flush=True)
    return 0


def _record_until_stopped(recorder: Recorder, progress: Progress, duration: float,
                          stop: Any) -> None:
    print(f"recording {', '.join(recorder.keyexprs)} into {progress.output} (Ctrl-C stops)",
          file=sys.stderr, flush=True)
    deadline = clock.monotonic() + duration if duration > 0 else None
    while not stop.is_set() and not recorder.failed.is_set():
        wait = PROGRESS_PERIOD_S
        if deadline is not None:
            wait = min(wait, deadline - clock.monotonic())
            if wait <= 0:
                break
        if stop.wait(wait):
            break
        progress.update()
        recorder.silence.check()


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
