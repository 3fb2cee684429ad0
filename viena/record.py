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

`viena record -o DIR --split-mb N --split-s S [--keep-gb G | --keep-share F]` records a
drive, the black box's way (common/drive_files.py): numbered files `DIR/<drive>_0001.mcap`,
..., each closed at N MB or S seconds, each starting with the latched topics' last samples,
the oldest closed files deleted to keep DIR within the budget; the `.part` files a killed
run left in DIR are repaired first.

Zenoh's threads only stamp and queue each sample; one thread writes, so a slow disk
delays the file, not the dataflow. Nothing on the keys for a few seconds is said on
stderr; a recording that got nothing at all is not kept, and the exit status is 1.
"""
from __future__ import annotations

import argparse
import socket
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from viena.common import clock
from viena.common.drive_files import MB, DriveWriter, budget_bytes
from viena.common.paths import drives_dir
from viena.common.recorder import FLUSH_PERIOD_S, Recorder, SampleWriter
from viena.common.recording import RecordingError, RecordingWriter, human_bytes, repair
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, SilenceWarning, add_timeout_flag, guarded, key_expressions, tool_logging

__all__ = ["FLUSH_PERIOD_S", "Recorder", "SampleWriter", "build_parser", "main", "run"]
PROGRESS_PERIOD_S = 0.5
#: how often the progress line is printed when stderr is not a terminal (a log file)
LOG_PERIOD_S = 10.0


def default_output() -> str:
    return datetime.fromtimestamp(clock.time(), UTC).strftime("viena-%Y%m%d-%H%M%S.mcap")


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena record", description=__doc__)
    parser.add_argument("keyexprs", nargs="*", metavar="KEYEXPR",
                        help="key expressions to record (default viena/**)")
    parser.add_argument("-o", "--output", metavar="FILE", default=None,
                        help="the MCAP file to write (default viena-<UTC time>.mcap); with --split-* "
                             "or --keep-*: the directory of a drive")
    parser.add_argument("--split-mb", type=float, default=None, metavar="N",
                        help="record a drive into the directory -o: a new file every N MB (0: no limit)")
    parser.add_argument("--split-s", type=float, default=None, metavar="S",
                        help="record a drive into the directory -o: a new file every S seconds (0: no limit)")
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--keep-gb", type=float, default=None, metavar="G",
                        help="a drive's budget: delete the oldest closed files in the directory to keep "
                             "them within G GB")
    budget.add_argument("--keep-share", type=float, default=None, metavar="F",
                        help="a drive's budget as a share (0-1) of the free space at start plus what "
                             "the directory's drives hold")
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
        where = f"{path} ({human_bytes(path.stat().st_size)})"
        if isinstance(r.writer, DriveWriter):
            d = r.writer
            where = f"{d.directory}: {d.number} files of drive {d.drive} ({human_bytes(d.size)}), the last {where}"
        print(f"recorded {r.samples} samples on {r.writer.keys} keys in "
              f"{clock.monotonic() - self._t0:.1f} s into {where}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    return guarded("viena record", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    if args.repair is not None:
        return _repair(args)
    link = Connection(args)
    keyexprs = key_expressions(args.keyexprs or [link.keys.all if args.car or "car" in link.toml
                                                 else "viena/**"])
    output = Path(args.output or (drives_dir() if is_drive(args) else default_output()))
    metadata = {"keyexprs": " ".join(keyexprs), "car": link.car, "host": socket.gethostname(),
                "started": datetime.fromtimestamp(clock.time(), UTC).isoformat(timespec="seconds")}
    writer = _writer(args, output, metadata)
    stop = stop_on_signals()
    try:
        session = link.open(stop, args.timeout)
    except Fail:
        writer.discard()
        raise
    if session is None:
        writer.discard()
        raise Fail("stopped before the router answered: nothing recorded")
    silence = SilenceWarning("viena record", keyexprs)
    recorder = Recorder(session, keyexprs, writer, on_sample=silence.heard)
    progress = Progress(recorder, output, args.quiet)
    try:
        recorder.start()
        _record_until_stopped(recorder, progress, args.duration, stop, silence)
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


def is_drive(args: argparse.Namespace) -> bool:
    """A drive of split files in a directory, rather than one file."""
    flags = (args.split_mb, args.split_s, args.keep_gb, args.keep_share)
    return any(f is not None for f in flags)


def _writer(args: argparse.Namespace, output: Path, metadata: dict[str, str]) -> SampleWriter:
    """The file, or the drive, the flags ask for; Fail if it cannot be written."""
    drive = is_drive(args)
    if drive and args.foxglove:
        raise Fail("--foxglove writes one file: not with --split-* or --keep-*", status=2)
    if drive and any(v is not None and v < 0 for v in (args.split_mb, args.split_s)):
        raise Fail("--split-mb and --split-s take a number >= 0 (0: no limit)", status=2)
    if args.keep_gb is not None and not args.keep_gb > 0:      # 0 would delete every drive there
        raise Fail("--keep-gb takes G > 0", status=2)
    if args.keep_share is not None and not 0 < args.keep_share <= 1:
        raise Fail("--keep-share takes a share of the free space, 0 < F <= 1", status=2)
    try:
        if drive:
            return _drive_writer(args, output, metadata)
        if args.foxglove:
            from viena.foxglove_export import FoxgloveWriter  # the SDK only when asked for
            return FoxgloveWriter(output, metadata=metadata)
        return RecordingWriter(output, metadata=metadata)
    except OSError as exc:
        raise Fail(f"cannot write {output}: {exc.strerror or exc}") from None


def _drive_writer(args: argparse.Namespace, directory: Path, metadata: dict[str, str]) -> DriveWriter:
    def say(line: str) -> None:
        print(f"viena record: {line}", file=sys.stderr, flush=True)

    keep = budget_bytes(directory, args.keep_gb, args.keep_share)
    if keep is not None and not args.keep_gb:
        say(f"keeping {directory} within {human_bytes(keep)} ({args.keep_share:g} of what the disk has)")
    return DriveWriter(directory, split_bytes=int((args.split_mb or 0) * MB), split_s=args.split_s or 0.0,
                       keep_bytes=keep, metadata=metadata, say=say)


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
                          stop: Any, silence: SilenceWarning) -> None:
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
        silence.check()


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
