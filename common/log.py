"""Logging for every process: one line per event, to stderr, where supervisor collects it."""
from __future__ import annotations

import logging
import sys

from viena.common import clock as clocks

FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"


def setup_logging(level: str | int = "INFO") -> None:
    if isinstance(level, str):
        level = level.upper()
    logging.basicConfig(stream=sys.stderr, level=level, format=FORMAT, force=True)
    try:
        import zenoh
        zenoh.init_log_from_env_or("error")
    except Exception:  # zenoh's Rust logger can only be set once per process
        pass


class Throttled:
    """Say each cause once per interval, with how many times it came meanwhile: a flood of
    bad input (10,000 a second) is a line every `interval_s`, not 91 KB in 5 s."""

    def __init__(self, logger: logging.Logger, what: str, interval_s: float = 10.0,
                 level: int = logging.WARNING, clock=None):
        self._log, self._what, self.interval_s, self._level = logger, what, interval_s, level
        self._clock = clock or clocks.monotonic
        self._last: dict[str, float] = {}
        self._quiet: dict[str, int] = {}

    def log(self, cause: str, detail: str = "") -> bool:
        """True if this one was written (with `detail`, which does not make a new cause)."""
        now = self._clock()
        last = self._last.get(cause)
        if last is not None and now - last < self.interval_s:
            self._quiet[cause] = self._quiet.get(cause, 0) + 1
            return False
        self._last[cause] = now
        quiet = self._quiet.pop(cause, 0)
        more = f" [{quiet} more since it was last logged]" if quiet else ""
        self._log.log(self._level, "%s: %s%s%s", self._what, cause, f" ({detail})" if detail else "", more)
        return True
