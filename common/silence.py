"""When a device has gone quiet: nothing heard from it for longer than its silence timeout.

A port can stay open while the device behind it says nothing (a receiver that lost its
configuration, a board that hung, a cable that is half out); only the silence shows it.
The drivers stamp what they receive with the host clock (``viena.common.clock.time_ns``),
so the watch keeps that clock and a driver's stamp can be handed over as it is.

The timeout is ``timeout_s``, or, with ``epochs`` given, the larger of that and ``epochs``
times the median interval between the device's recent epochs: a 1 Hz receiver whose
epochs come 1.06 s apart gets 3.2 s with ``epochs=3``, a 20 Hz one keeps ``timeout_s``.
"""
from __future__ import annotations

import statistics
import threading
from collections import deque
from collections.abc import Callable

from viena.common import clock as clocks

#: how many recent epoch intervals the median is taken over
EPOCH_WINDOW = 15


class SilenceWatch:
    """Fed by whoever receives (`heard`, `epoch`, from any thread); asked by the supervisor
    (`expired`)."""

    def __init__(self, timeout_s: float, *, epochs: float | None = None,
                 clock: Callable[[], int] = clocks.time_ns):
        self.min_timeout_s = timeout_s
        self.epochs = epochs
        self._clock = clock
        self._lock = threading.Lock()
        self._intervals_s: deque[float] = deque(maxlen=EPOCH_WINDOW)
        self._last_ns = clock()
        self._last_epoch_ns: int | None = None

    def restart(self) -> None:
        """Count the quiet from now (the device was just opened); the gap before it was
        ours, not the device's pace, so no interval spans it."""
        with self._lock:
            self._last_ns = self._clock()
            self._last_epoch_ns = None

    def heard(self, t_ns: int | None = None) -> None:
        """The device said something at `t_ns` (default: now)."""
        t_ns = self._clock() if t_ns is None else t_ns
        with self._lock:
            self._last_ns = max(self._last_ns, t_ns)

    def epoch(self, t_ns: int | None = None) -> None:
        """The device finished an epoch at `t_ns` (default: now); also a sign of life."""
        t_ns = self._clock() if t_ns is None else t_ns
        with self._lock:
            if self._last_epoch_ns is not None and t_ns > self._last_epoch_ns:
                self._intervals_s.append((t_ns - self._last_epoch_ns) / 1e9)
            self._last_epoch_ns = t_ns
            self._last_ns = max(self._last_ns, t_ns)

    @property
    def timeout_s(self) -> float:
        with self._lock:
            if not self.epochs or not self._intervals_s:
                return self.min_timeout_s
            return max(self.min_timeout_s, self.epochs * statistics.median(self._intervals_s))

    def quiet_s(self) -> float:
        with self._lock:
            return (self._clock() - self._last_ns) / 1e9

    def expired(self) -> bool:
        return self.quiet_s() > self.timeout_s
