"""Health: what a service tells the world once a second about how it is doing."""
from __future__ import annotations

import threading
import time

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


class Health:
    """Counters a service bumps from any thread; `snapshot()` turns them into a sample."""

    def __init__(self, service: str, unit: str | None = None):
        self.service, self.unit = service, unit
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._errors: dict[str, int] = {}
        self._state: dict = {}
        self._last_counts: dict[str, int] = {}
        self._last_snapshot = time.monotonic()
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
        self._last_sample = time.monotonic()

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
        now = time.monotonic()
        with self._lock:
            dt = max(now - self._last_snapshot, 1e-6)
            rates = {k: (v - self._last_counts.get(k, 0)) / dt for k, v in self._counts.items()}
            self._last_counts = dict(self._counts)
            self._last_snapshot = now
            self._seq += 1
            return {
                "t": time.time_ns(),
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
