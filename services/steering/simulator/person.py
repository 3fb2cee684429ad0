"""The person at the wheel after power-up, as the sim car and the tests play them.

They read the steering's state as a person reads the monitor: when it has said
"calibrating" for a while (its sweep was refused, or thrown away as a glitch) and they are
not sweeping already, they turn the wheel lock to lock again. Without them a twin sweeps
once, and a sweep the service threw away would wait for ever.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

from viena.common import clock as clocks
from viena.services.steering.simulator.epos_twin import EposTwin

#: how long the steering says "calibrating" before the person notices and sweeps again
NOTICES_S = 2.0


class PersonAtTheWheel:
    def __init__(self, wheels: Sequence[EposTwin], notices_s: float = NOTICES_S,
                 clock: Callable[[], float] = clocks.monotonic):
        self.wheels = list(wheels)
        self.notices_s = notices_s
        self.clock = clock
        self._calibrating_since: float | None = None

    def read(self, state: dict) -> bool:
        """One steering state (decoded); True if it made the person sweep again."""
        if state["phase"] != "calibrating" or state["armed"]:
            self._calibrating_since = None
            return False
        now = self.clock()
        if self._calibrating_since is None:
            self._calibrating_since = now
            return False
        if now - self._calibrating_since <= self.notices_s:
            return False
        self._calibrating_since = None
        return any([wheel.ask_for_sweep() for wheel in self.wheels])
