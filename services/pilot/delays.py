"""How long the pilot's steps take, as health shows it: p50 and p99 per window of samples."""
from __future__ import annotations


class Window:
    """p50 and p99 of a delay over the last 500 times, set in health (ms) once per 500."""

    def __init__(self, health, name: str, size: int = 500):
        self._health, self._name, self._size = health, name, size
        self._values_s: list[float] = []

    def add(self, value_s: float) -> None:
        self._values_s.append(value_s)
        if len(self._values_s) >= self._size:
            ordered = sorted(self._values_s)
            self._health.set(self._name, {"p50": round(ordered[self._size // 2 - 1] * 1e3, 2),
                                          "p99": round(ordered[self._size * 99 // 100 - 1] * 1e3, 2)})
            self._values_s.clear()
