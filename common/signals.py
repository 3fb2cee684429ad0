"""SIGTERM and SIGINT as a threading.Event, without the deadlock.

A Python signal handler runs in the main thread, between two of its bytecodes, and that
thread is usually parked in `Event.wait()`. On its way into and out of the wait it holds
the event's lock, which is not re-entrant: a handler that calls `event.set()` just then
waits for that lock for ever, and the process no longer stops for anything but SIGKILL
(tests/test_signals.py makes it happen). So the handlers here only start a bare thread
(`_thread`, which takes none of `threading`'s locks either), and that thread does the work
as soon as the main thread lets go.
"""
from __future__ import annotations

import _thread
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterable

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
#: how long any viena program may take to stop once told (supervisor waits 3 s, then kills)
STOP_DEADLINE_S = 2.0


def call_on_signals(action: Callable[[int], None], signals: Iterable[int] = STOP_SIGNALS) -> None:
    """From now on, `action(signum)` runs on a thread of its own when one of `signals`
    comes (main thread only, as for any handler)."""
    def handler(signum: int, _frame) -> None:
        _thread.start_new_thread(action, (signum,))
    for sig in signals:
        signal.signal(sig, handler)


def stop_on_signals(signals: Iterable[int] = STOP_SIGNALS) -> threading.Event:
    """An event set by SIGTERM or SIGINT (Ctrl-C): how a program learns to stop."""
    stop = threading.Event()
    call_on_signals(lambda _signum: stop.set(), signals)
    return stop


def exit_if_stuck(log: logging.Logger, deadline_s: float = STOP_DEADLINE_S - 0.2) -> None:
    """From now on, exit anyway after `deadline_s`: the stop deadline is a promise to
    supervisor and to the person at Ctrl-C, kept even if a device or zenoh hangs while
    closing (a router flooded with denials just before did, in CI)."""
    def force() -> None:
        log.warning("stop took longer than %.1f s: exiting anyway", deadline_s)
        logging.shutdown()
        os._exit(0)
    timer = threading.Timer(deadline_s, force)
    timer.daemon = True
    timer.start()
