"""`viena hz KEYEXPR`: how fast samples come, how evenly, and how many bytes a second.

Once a second, one line per key the expression matches (as `ros2 topic hz` does):

    viena/elettra/imu/razor0/sample: 100.02 Hz, period 10.00 ms (std 0.41, min 8.90, max 11.32 ms),
        9.4 kB/s (94 B/sample), 100 samples

measured over the last --window samples, at their arrival on this machine (so the
network's jitter is in it). The arithmetic is `RateMeter`, a plain object given arrival
times and sizes, which `viena list` uses too.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.recording import human_bytes
from viena.tool import Connection, Fail, SilenceWarning, add_timeout_flag, guarded, key_expressions, tool_logging

WINDOW = 200
PRINT_PERIOD_S = 1.0


@dataclass(frozen=True)
class Rates:
    """What a window of arrivals says."""

    samples: int
    rate_hz: float | None            # None below two samples
    period_s: float | None
    period_std_s: float | None
    period_min_s: float | None
    period_max_s: float | None
    bytes_per_s: float | None
    bytes_per_sample: float

    def line(self) -> str:
        if self.rate_hz is None:
            return f"{self.samples} sample{'s' if self.samples != 1 else ''}, too few for a rate"
        ms = 1e3
        return (f"{self.rate_hz:.2f} Hz, period {self.period_s * ms:.2f} ms (std "
                f"{self.period_std_s * ms:.2f}, min {self.period_min_s * ms:.2f}, max "
                f"{self.period_max_s * ms:.2f} ms), {human_bytes(self.bytes_per_s)}/s "
                f"({self.bytes_per_sample:.0f} B/sample), {self.samples} samples")


class RateMeter:
    """The last `window` arrivals of one key: `add(t_s, n_bytes)`, then `rates()`."""

    def __init__(self, window: int = WINDOW):
        self._times: deque[float] = deque(maxlen=window)
        self._sizes: deque[int] = deque(maxlen=window)
        self.total = 0

    def add(self, t_s: float, n_bytes: int) -> None:
        self._times.append(t_s)
        self._sizes.append(n_bytes)
        self.total += 1

    def rates(self) -> Rates:
        import numpy as np

        n = len(self._times)
        mean_bytes = float(np.mean(self._sizes)) if n else 0.0
        if n < 2 or self._times[-1] <= self._times[0]:
            return Rates(n, None, None, None, None, None, None, mean_bytes)
        periods = np.diff(np.asarray(self._times))
        span = self._times[-1] - self._times[0]
        # the bytes that came in the span: every sample but the first, which opened it
        return Rates(n, (n - 1) / span, float(periods.mean()), float(periods.std()),
                     float(periods.min()), float(periods.max()),
                     float(sum(self._sizes) - self._sizes[0]) / span, mean_bytes)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena hz", description=__doc__)
    parser.add_argument("keyexpr", metavar="KEYEXPR",
                        help="a key or key expression, e.g. viena/elettra/imu/razor0/sample")
    parser.add_argument("--window", type=int, default=WINDOW, metavar="N",
                        help=f"measure over the last N samples of each key (default {WINDOW})")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="exit after S seconds (default: until Ctrl-C)")
    add_timeout_flag(parser)
    add_common_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena hz", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    if args.window < 2:
        raise Fail("--window must be at least 2", 2)
    link = Connection(args)
    [keyexpr] = key_expressions([args.keyexpr])
    stop = stop_on_signals()
    session = link.open(stop, args.timeout)
    if session is None:
        return 0
    meters: dict[str, RateMeter] = {}
    lock = threading.Lock()
    silence = SilenceWarning("viena hz", [keyexpr])

    def on_sample(sample) -> None:         # zenoh's thread: stamp and count, nothing else
        now = time.monotonic()
        key = str(sample.key_expr)
        with lock:
            meter = meters.get(key)
            if meter is None:
                meter = meters[key] = RateMeter(args.window)
            meter.add(now, len(sample.payload))
        silence.heard()

    sub = session.declare_subscriber(keyexpr, on_sample)
    end = time.monotonic() + args.duration if args.duration > 0 else None
    try:
        while not stop.wait(PRINT_PERIOD_S if end is None else max(0.0, min(PRINT_PERIOD_S, end - time.monotonic()))):
            silence.check()
            with lock:
                lines = [f"{key}: {meter.rates().line()}" for key, meter in sorted(meters.items())]
            for line in lines:
                print(line, flush=True)
            if end is not None and time.monotonic() >= end:
                break
    except BrokenPipeError:
        pass
    finally:
        sub.undeclare()
        session.close()
    if not meters and not silence.said:
        raise Fail(f"nothing came on '{keyexpr}': is the key right? `viena list` shows what the "
                   f"car publishes")
    return 0 if meters else 1


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
