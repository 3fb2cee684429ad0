"""Logging for every process: one line per event, to stderr, where supervisor collects it."""
from __future__ import annotations

import logging
import sys

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
