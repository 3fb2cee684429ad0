"""Health: the counters a service bumps from any thread, made once a second into its
viena.health/1 sample (common/samples/health.py)."""
from __future__ import annotations

import threading

from viena.common import clock


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
