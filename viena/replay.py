"""`viena replay DRIVE`: publish a recording back into the dataflow with its timing.

DRIVE is one file (played alone), or a drive of the black box: its directory (its drive,
or the newest, or `--drive ID`) or its id; the drive's files then play as one, the
latched samples each file repeats at its start played once, the timing running on.

Samples go out on their recorded keys, with their recorded encodings and bytes, spaced as
they arrived at the recorder (log times), `--rate` times faster (0: as fast as the link
takes them). `--car NAME` moves every viena/<car>/ key to viena/NAME/, so a drive can be
replayed beside a live car. A recording cut short or damaged is played as far as it can
be read; replay then says where it stopped and exits with status 1.
"""
from __future__ import annotations

import argparse
import logging
import queue
import sys
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from viena.common import clock
from viena.common.errors import InputError
from viena.common.keys import ROOT, Keys
from viena.common.recording import KeyFilter, Recorded, open_source
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, add_drive_arguments, add_timeout_flag, guarded, key_expressions, tool_logging

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("viena.replay")
EARLY_S = 0.0002
STOP_SLICE_S = 0.1


def rename_car(key: str, car: str | None) -> str:
    """viena/<any car>/rest -> viena/<car>/rest; other keys unchanged."""
    if car is None:
        return key
    parts = key.split("/", 2)
    if len(parts) >= 2 and parts[0] == ROOT:
        return "/".join([ROOT, car, *parts[2:]])
    return key


@dataclass
class PlayStats:
    samples: int = 0
    keys: set = field(default_factory=set)
    passes: int = 0
    #: seconds the latest samples went out after their due time (empty for --rate 0)
    lateness_s: deque = field(default_factory=lambda: deque(maxlen=1_000_000))


class Player:
    """Publishes recorded samples on a session, paced by their log times."""

    def __init__(self, session, rate: float = 1.0, car: str | None = None):
        if rate < 0:
            raise ValueError("rate must be >= 0")
        self.session, self.rate, self.car = session, rate, car
        self._publishers: dict[tuple[str, str], zenoh.Publisher] = {}
        self.stats = PlayStats()

    def _publisher(self, key: str, encoding: str) -> zenoh.Publisher:
        import zenoh

        pub = self._publishers.get((key, encoding))
        if pub is None:
            # BLOCK: under congestion a replay is late rather than incomplete.
            pub = self._publishers[(key, encoding)] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding(encoding),
                congestion_control=zenoh.CongestionControl.BLOCK)
        return pub

    def play(self, messages: Iterable[Recorded], stop: Any) -> None:
        """One pass: the first sample goes out now, every other one at its log-time offset."""
        t0_log, t0 = 0, None           # the first sample's log time, and when it went out
        stats = self.stats
        for msg in messages:
            key = rename_car(msg.key, self.car)
            pub = self._publisher(key, msg.encoding)
            if self.rate > 0:
                if t0 is None:
                    t0_log, t0 = msg.log_time, clock.monotonic()
                due = t0 + (msg.log_time - t0_log) / 1e9 / self.rate
                if self._sleep_until(due, stop):
                    return
                pub.put(msg.data)
                stats.lateness_s.append(clock.monotonic() - due)
            else:
                if stop.is_set():
                    return
                pub.put(msg.data)
            stats.samples += 1
            stats.keys.add(key)
        stats.passes += 1

    @staticmethod
    def _sleep_until(due: float, stop: Any) -> bool:
        """Sleep until `due` (monotonic s); True if stopped first. A sleep wakes up more
        precisely than Event.wait, so the stop flag is only looked at between slices; a
        sample due within EARLY_S goes now, as sleeping that little overshoots more."""
        while True:
            wait = due - clock.monotonic()
            if wait <= EARLY_S:
                return stop.is_set()
            if stop.is_set():
                return True
            clock.sleep(min(wait, STOP_SLICE_S))

    def close(self) -> None:
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        self._publishers.clear()


class Prefetch:
    """Reads samples ahead in a thread, so that decompressing the next chunk of the file
    happens while the player waits, not when the next sample is due. The first sample
    is handed out once the read-ahead is full (or the file read), so that the reading
    does not compete with the first seconds of playing."""

    _END = object()

    def __init__(self, messages: Iterable[Recorded], depth: int = 20000):
        self._queue = clock.Queue(maxsize=depth)
        self._primed = clock.Event()
        self._closed = clock.Event()
        self._thread = clock.Thread(target=self._read, args=(messages,), name="replay-read",
                                        daemon=True)
        self._thread.start()

    def _read(self, messages) -> None:
        try:
            for msg in messages:
                if not self._offer(msg):
                    return
            self._offer(self._END)
        except BaseException as exc:            # handed to the player, raised there
            self._offer(exc)
        finally:
            self._primed.set()

    def _offer(self, item) -> bool:
        try:
            self._queue.put_nowait(item)
            return True
        except queue.Full:
            self._primed.set()
        while not self._closed.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def __iter__(self):
        try:
            self._primed.wait()
            while True:
                item = self._queue.get()
                if item is self._END:
                    return
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            self._closed.set()
            self._thread.join(timeout=1)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena replay", description=__doc__)
    add_drive_arguments(parser)
    parser.add_argument("--rate", type=float, default=1.0,
                        help="speed: 1 is as recorded, 2 twice as fast, 0 as fast as possible")
    parser.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    parser.add_argument("--keyexpr", nargs="+", metavar="KEYEXPR",
                        help="replay only keys these key expressions include (as recorded, "
                             "before --car renames them)")
    add_timeout_flag(parser)
    add_common_arguments(parser)
    parser._option_string_actions["--car"].help = (
        "publish under viena/NAME/ instead of the recorded car's keys (default: as recorded)")
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena replay", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    try:
        if args.rate < 0:
            raise InputError(f"--rate must be >= 0, got {args.rate}")
        if args.car is not None:
            Keys(args.car)                               # checks the name
        keys = KeyFilter(key_expressions(args.keyexpr) if args.keyexpr else None)
        recording = open_source(args.file, args.drive, say=lambda note: print(f"viena replay: {note}", file=sys.stderr))
    except (InputError, ValueError) as exc:
        raise Fail(str(exc), 2) from None
    link = Connection(args)

    stop = stop_on_signals()
    session = link.open(stop, args.timeout)
    if session is None:
        return 0
    player = Player(session, args.rate, args.car)
    # The reading thread must let the player in on time: switch threads every 0.5 ms
    # (Python's default is 5 ms) so that a due sample waits at most that for the GIL.
    sys.setswitchinterval(0.0005)
    t_start = clock.monotonic()
    damaged = False
    try:
        while not stop.is_set():
            player.play(Prefetch(recording.messages(keys)), stop)
            if not damaged:                     # say it once, even when looping
                for line in recording.report():
                    damaged = True
                    print(f"viena replay: {recording.path}: {line}", file=sys.stderr, flush=True)
            if not args.loop or player.stats.samples == 0:
                break
    except InputError as exc:
        print(f"viena replay: {exc}", file=sys.stderr)
        return 2
    finally:
        player.close()
        session.close()
    stats = player.stats
    timing = ""
    if stats.lateness_s:
        import numpy as np

        timing = f"; 99 % within {np.percentile(stats.lateness_s, 99) * 1e3:.1f} ms of their time"
    print(f"replayed {stats.samples} samples on {len(stats.keys)} keys in "
          f"{clock.monotonic() - t_start:.1f} s ({stats.passes} "
          f"{'pass' if stats.passes == 1 else 'passes'}){timing}", file=sys.stderr)
    return 1 if damaged else 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
