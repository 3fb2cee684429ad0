"""Health: what a service tells the world once a second about how it is doing."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

from viena.common import clock
from viena.common.display import Alert, fields_line, fmt_age, fmt_map, number
from viena.common.schema import F, Schema

HEALTH = Schema("viena.health/1", {
    "t": F.time,
    "seq": F.int,
    "service": F.str,
    "unit": F.optional(F.str),
    "uptime_s": F.float,
    "rates_hz": F.map,            # events per second over the last period, by name
    "counts": F.map,              # totals since start, by name
    "errors": F.map,              # error totals since start, by name
    "last_sample_age_s": F.optional(F.float),
    "state": F.optional(F.map),   # anything else the service wants seen (connected, ...)
})

# What every device service reports about its device, under these names and no others: the
# device supervisor (common/supervisor.py) keeps them, the monitor reads them.
RECONNECTS = "reconnects"               # counts: the device came back after it was lost
CONNECT_FAILURES = "connect_failures"   # errors: an attempt to open or start it failed
PORT_FAILURES = "port_failures"         # errors: the open port failed (unplugged, I/O error)
SILENCES = "silences"                   # errors: it said nothing for its silence timeout
INTERNAL_ERRORS = "internal_errors"     # errors: handling it raised (a bug); it was reopened
DEVICE_ERRORS = (CONNECT_FAILURES, PORT_FAILURES, SILENCES, INTERNAL_ERRORS)
CONNECTED = "connected"                 # state: True while it is open and being served
LAST_ERROR = "last_error"               # state: why it was last lost or not reached
PORT = "port"                           # state: its URL


def _numbers(v) -> dict[str, float]:
    if not isinstance(v, dict):
        return {}
    return {str(k): n for k, x in v.items() if (n := number(x)) is not None}


@dataclass(frozen=True)
class HealthReport:
    """A health sample as a person reads it, from anything that came on a health key."""

    uptime_s: float | None = None               # as of now: reported, plus the sample's age
    rates_hz: dict = field(default_factory=dict)    # of events that happened at least once
    errors: dict = field(default_factory=dict)      # the error totals that are not zero
    last_sample_age_s: float | None = None      # as reported (the sample's age says how old)
    reconnects: int | None = None               # device services count them (RECONNECTS)
    state: dict = field(default_factory=dict)

    @classmethod
    def of(cls, sample, age_s: float = 0.0) -> HealthReport:
        """The report in `sample` (any value), received `age_s` ago."""
        if not isinstance(sample, dict):
            return cls()
        uptime_s = number(sample.get("uptime_s"))
        counts = _numbers(sample.get("counts"))
        reconnects = counts.get(RECONNECTS)
        state = sample.get("state")
        return cls(
            uptime_s=None if uptime_s is None else uptime_s + age_s,
            # a rate of something that never happened (unknown_messages 0.0) is only noise
            rates_hz={k: v for k, v in _numbers(sample.get("rates_hz")).items() if v or counts.get(k)},
            errors={k: v for k, v in _numbers(sample.get("errors")).items() if v},
            last_sample_age_s=number(sample.get("last_sample_age_s")),
            reconnects=None if reconnects is None else int(reconnects),
            state=state if isinstance(state, dict) else {})

    def cells(self) -> dict[str, str]:
        """How the monitor shows it, one cell per column."""
        return {
            "up": fmt_age(self.uptime_s),
            "rates Hz": fmt_map(self.rates_hz),
            "errors": Alert(fmt_map(self.errors, 0)) if self.errors else "-",
            "last sample": fmt_age(self.last_sample_age_s),
            "reconnects": "-" if self.reconnects is None else str(self.reconnects),
            "state": fields_line(self.state),
        }


def monitor_view(sample, age_s: float = 0.0) -> dict[str, str]:
    """How the monitor shows a health sample received `age_s` ago."""
    return HealthReport.of(sample, age_s).cells()


class Health:
    """Counters a service bumps from any thread; `snapshot()` turns them into a sample."""

    def __init__(self, service: str, unit: str | None = None):
        self.service, self.unit = service, unit
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._errors: dict[str, int] = {}
        self._state: dict = {}
        self._last_counts: dict[str, int] = {}
        self._last_snapshot = clock.monotonic()
        self._started = self._last_snapshot
        self._last_sample: float | None = None
        self._seq = 0

    def count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counts[name] = self._counts.get(name, 0) + n

    def error(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._errors[name] = self._errors.get(name, 0) + n

    def mark_sample(self) -> None:
        self._last_sample = clock.monotonic()

    def set(self, name: str, value) -> None:
        with self._lock:
            self._state[name] = value

    def errors(self) -> dict[str, int]:
        with self._lock:
            return dict(self._errors)

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def snapshot(self) -> dict:
        now = clock.monotonic()
        with self._lock:
            dt = max(now - self._last_snapshot, 1e-6)
            rates = {k: (v - self._last_counts.get(k, 0)) / dt for k, v in self._counts.items()}
            self._last_counts = dict(self._counts)
            self._last_snapshot = now
            self._seq += 1
            return {
                "t": clock.time_ns(),
                "seq": self._seq,
                "service": self.service,
                "unit": self.unit,
                "uptime_s": now - self._started,
                "rates_hz": rates,
                "counts": dict(self._counts),
                "errors": dict(self._errors),
                "last_sample_age_s": None if self._last_sample is None else now - self._last_sample,
                "state": dict(self._state),
            }
