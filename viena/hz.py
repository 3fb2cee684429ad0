"""`viena hz KEYEXPR`: how fast samples come, how evenly, and how many bytes a second.

Once a second, one line per key the expression matches (as `ros2 topic hz` does):

    viena/elettra/imu/razor0/sample: 100.02 Hz, period 10.00 ms (std 0.41, min 8.90, max 11.32 ms),
        9.4 kB/s (94 B/sample), 100 samples

measured over the last --window samples, at their arrival on this machine (so the
network's jitter is in it). The arithmetic is `RateMeter`, a plain object given arrival
times and sizes, which `viena list` uses too.

A GNSS fix key (viena.gnss.fix) adds its solution types and the age of the corrections
in them; the corrections key (viena.gnss.corrections) its correction bytes a second and
the RTCM message types in them, over the same window (`SolutionMix`, `CorrectionsMix`,
which `viena info` uses for a recording):

    viena/elettra/gnss/gnss0/fix: 20.00 Hz, ... 200 samples; NARROW_INT 92 %, NARROW_FLOAT 8 %
        (fixed 92 %, float 8 %); diff age p50 1.0 s, max 1.9 s; base 0042
    viena/elettra/gnss/corrections: 1.00 Hz, ... 10 samples; RTCMV3 1.1 kB/s of corrections,
        types 1005 x1, 1077 x10, 1087 x10, 1230 x1; base 42
"""
from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

from viena.common.errors import SampleError
from viena.common.recording import decode_value, human_bytes, schema_name
from viena.common.session import add_common_arguments
from viena.common.signals import stop_on_signals
from viena.tool import Connection, Fail, SilenceWarning, add_timeout_flag, guarded, key_expressions, tool_logging

WINDOW = 200
PRINT_PERIOD_S = 1.0
#: the schemas whose samples say more than their rate (by the name's prefix: any version)
FIX_SCHEMA = "viena.gnss.fix/"
CORRECTIONS_SCHEMA = "viena.gnss.corrections/"


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
        per_s = "?" if self.bytes_per_s is None else human_bytes(self.bytes_per_s)   # set with the rate
        return (f"{self.rate_hz:.2f} Hz, period {_ms(self.period_s)} ms (std "
                f"{_ms(self.period_std_s)}, min {_ms(self.period_min_s)}, max "
                f"{_ms(self.period_max_s)} ms), {per_s}/s "
                f"({self.bytes_per_sample:.0f} B/sample), {self.samples} samples")


def _ms(seconds: float | None) -> str:
    return "?" if seconds is None else f"{seconds * 1e3:.2f}"


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


def _share(n: int, total: int) -> str:
    pct = 100.0 * n / total
    return "<1 %" if 0 < pct < 0.5 else f"{pct:.0f} %"


def _ids(ids) -> str:
    ids = sorted({str(i) for i in ids if i not in (None, "")})
    return ", ".join(ids[:4]) + (f" +{len(ids) - 4}" if len(ids) > 4 else "")


def _number(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and v == v else None


class SolutionMix:
    """What a run of fixes says of their solutions: the share of each position type (and
    of each kind: single, dgps, float, fixed...), the age of the corrections while a
    solution used them, the base stations named. The last `window` fixes (None: all)."""

    def __init__(self, window: int | None = WINDOW):
        self._fixes: deque[tuple[str, str, float | None, str | None]] = deque(maxlen=window)

    def add(self, fix) -> None:
        """One decoded fix (any map: a field missing or wrong is left out, never raised)."""
        from viena.common.samples.fix import solution_kind

        if not isinstance(fix, dict):
            return
        pos_type = fix.get("pos_type", "SINGLE")         # as read_fix reads a source without it
        pos_type = pos_type if isinstance(pos_type, str) else "?"
        kind = solution_kind(pos_type)
        differential = kind not in ("none", "single")
        age = _number(fix.get("diff_age_s")) if differential else None
        base = fix.get("base_id") if differential and isinstance(fix.get("base_id"), str) else None
        self._fixes.append((pos_type, kind, age, base or None))

    def __len__(self) -> int:
        return len(self._fixes)

    def _counts(self) -> tuple[Counter, Counter, list[float], list[str]]:
        types = Counter(t for t, _, _, _ in self._fixes)
        kinds = Counter(k for _, k, _, _ in self._fixes)
        ages = [a for _, _, a, _ in self._fixes if a is not None]
        return types, kinds, ages, sorted({b for *_, b in self._fixes if b})

    def summary(self) -> dict:
        """Shares by position type and by kind (most first), diff age p50/max (s) over the
        fixes that used corrections (None if none did), the base ids seen."""
        n = len(self._fixes) or 1
        types, kinds, ages, bases = self._counts()
        return {"fixes": len(self._fixes),
                "pos_types": {t: c / n for t, c in types.most_common()},
                "kinds": {k: c / n for k, c in kinds.most_common()},
                "diff_age_s": {"p50": statistics.median(ages), "max": max(ages)} if ages else None,
                "base_ids": bases}

    def line(self) -> str:
        n = len(self._fixes)
        if not n:
            return "no fixes"
        types, kinds, ages, bases = self._counts()
        text = ", ".join(f"{t} {_share(c, n)}" for t, c in types.most_common())
        if set(kinds) != {"single"}:
            text += " (" + ", ".join(f"{k} {_share(c, n)}" for k, c in kinds.most_common()) + ")"
        text += ("; no corrections in use" if not ages else
                 f"; diff age p50 {statistics.median(ages):.1f} s, max {max(ages):.1f} s")
        return text + (f"; base {_ids(bases)}" if bases else "")


class CorrectionsMix:
    """What a run of corrections samples carried: their data bytes a second (over the
    span of their receive times `t`), format, RTCM message types and base ids. The last
    `window` samples (None: all)."""

    def __init__(self, window: int | None = WINDOW):
        self._samples: deque[tuple[int | None, int, str, tuple[int, ...], str | None]] = deque(maxlen=window)

    def add(self, sample) -> None:
        """One decoded corrections sample (any map: what is wrong in it is left out)."""
        if not isinstance(sample, dict):
            return
        t = sample.get("t") if type(sample.get("t")) is int else None
        data = sample.get("data")
        size = len(data) if isinstance(data, (bytes, bytearray)) else 0
        said_types = sample.get("types")
        types = said_types if isinstance(said_types, (list, tuple)) else ()
        base = sample.get("base_id")
        self._samples.append((t, size, str(sample.get("format") or "?"),
                              tuple(x for x in types if type(x) is int), None if base in (None, "") else str(base)))

    def __len__(self) -> int:
        return len(self._samples)

    def summary(self) -> dict:
        """Data bytes, and a second (None below two timed samples), formats, how many
        messages of each type, base ids."""
        timed = [(t, size) for t, size, *_ in self._samples if t is not None]
        rate = None
        if len(timed) >= 2:
            t0, size0 = min(timed)
            span_s = (max(t for t, _ in timed) - t0) / 1e9
            if span_s > 0:      # the bytes that came in the span: all but the first sample's
                rate = (sum(size for _, size in timed) - size0) / span_s
        types = Counter(x for _, _, _, ts, _ in self._samples for x in ts)
        return {"samples": len(self._samples), "data_bytes": sum(s for _, s, *_ in self._samples),
                "data_bytes_per_s": rate, "formats": sorted({f for _, _, f, _, _ in self._samples}),
                "types": dict(sorted(types.items())), "base_ids": sorted({b for *_, b in self._samples if b})}

    def line(self) -> str:
        if not self._samples:
            return "no corrections"
        s = self.summary()
        rate = s["data_bytes_per_s"]
        text = "/".join(s["formats"]) + (f" {human_bytes(s['data_bytes'])}" if rate is None
                                         else f" {human_bytes(rate)}/s") + " of corrections"
        if s["types"]:
            text += ", types " + ", ".join(f"{t} x{c}" for t, c in s["types"].items())
        return text + (f"; base {_ids(s['base_ids'])}" if s["base_ids"] else "")


def content_mix(schema: str, window: int | None = WINDOW) -> SolutionMix | CorrectionsMix | None:
    """What is worth reading inside the samples of a schema (by name), or None."""
    if schema.startswith(FIX_SCHEMA):
        return SolutionMix(window)
    if schema.startswith(CORRECTIONS_SCHEMA):
        return CorrectionsMix(window)
    return None


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


class KeyRates:
    """Per key heard: its rate meter and, for a schema that says more than its rate, its mix
    and the payloads not yet decoded. zenoh's thread adds (`on_sample`), the printing
    thread decodes and reads (`lines`)."""

    def __init__(self, window: int, on_heard: Callable[[], None]):
        self.window = window
        self.meters: dict[str, RateMeter] = {}
        self.mixes: dict[str, SolutionMix | CorrectionsMix] = {}
        self.payloads: dict[str, deque[tuple[bytes, str]]] = {}    # of the keys with a mix, not yet read
        self._lock = threading.Lock()
        self._on_heard = on_heard

    def on_sample(self, sample) -> None:         # zenoh's thread: stamp, count, keep a fix's bytes
        now = time.monotonic()
        key = str(sample.key_expr)
        with self._lock:
            meter = self.meters.get(key)
            if meter is None:
                meter = self.meters[key] = RateMeter(self.window)
                encoding = str(sample.encoding)
                mix = content_mix(schema_name(encoding), self.window)
                if mix is not None:
                    self.mixes[key], self.payloads[key] = mix, deque(maxlen=self.window)
            meter.add(now, len(sample.payload))
            if key in self.payloads:
                self.payloads[key].append((sample.payload.to_bytes(), str(sample.encoding)))
        self._on_heard()

    def read_payloads(self) -> None:            # the printing thread decodes what came
        with self._lock:
            taken = {key: waiting for key, waiting in self.payloads.items() if waiting}
            for key in taken:
                self.payloads[key] = deque(maxlen=self.window)
        for key, waiting in taken.items():
            for data, encoding in waiting:
                try:
                    self.mixes[key].add(decode_value(data, encoding))
                except SampleError:
                    pass

    def lines(self) -> list[str]:
        """One line per key, its rates and its mix (a mix is read and fed by this thread alone)."""
        self.read_payloads()
        with self._lock:
            rates = [(key, meter.rates()) for key, meter in sorted(self.meters.items())]
        lines = []
        for key, measured in rates:
            mix = self.mixes.get(key)
            lines.append(f"{key}: {measured.line()}" + (f"; {mix.line()}" if mix is not None and len(mix) else ""))
        return lines


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
    silence = SilenceWarning("viena hz", [keyexpr])
    heard = KeyRates(args.window, silence.heard)
    sub = session.declare_subscriber(keyexpr, heard.on_sample)
    end = time.monotonic() + args.duration if args.duration > 0 else None
    try:
        while not stop.wait(PRINT_PERIOD_S if end is None else max(0.0, min(PRINT_PERIOD_S, end - time.monotonic()))):
            silence.check()
            for line in heard.lines():
                print(line, flush=True)
            if end is not None and time.monotonic() >= end:
                break
    except BrokenPipeError:
        pass
    finally:
        sub.undeclare()
        session.close()
    if not heard.meters and not silence.said:
        raise Fail(f"nothing came on '{keyexpr}': is the key right? `viena list` shows what the "
                   f"car publishes")
    return 0 if heard.meters else 1


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
