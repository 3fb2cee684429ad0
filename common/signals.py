"""SIGTERM and SIGINT as a threading.Event, without the deadlock.

A Python signal handler runs in the main thread, between two of its bytecodes, and that
thread is usually parked in `Event.wait()`. On its way into and out of the wait it holds
the event's lock, which is not re-entrant: a handler that calls `event.set()` just then
waits for that lock for ever, and the process no longer stops for anything but SIGKILL
(tests/test_signals.py makes it happen). So the handlers here only start a bare thread
(`_thread`, which takes none of `threading`'s locks either), and that thread does the work
as soon as the main thread lets go.

And the kernel may hand a process's SIGTERM to any of its threads, one of zenoh's as well
as the main one. Python then only notes it: the handler runs when the main thread next
runs bytecode, and a main thread parked in a wait without end never does (a flooded
`viena router` ignored SIGTERM so, in CI). So the stop event's waits wake every
SIGNAL_CHECK_S to let pending handlers run.
"""
from __future__ import annotations

import _thread
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
#: how long any viena program may take to stop once told (supervisor waits 3 s, then kills)
STOP_DEADLINE_S = 2.0
#: how often a main thread waiting on its stop event runs the signal handlers due
SIGNAL_CHECK_S = 0.25


def call_on_signals(action: Callable[[int], None], signals: Iterable[int] = STOP_SIGNALS) -> None:
    """From now on, `action(signum)` runs on a thread of its own when one of `signals`
    comes (main thread only, as for any handler)."""
    def handler(signum: int, _frame) -> None:
        _thread.start_new_thread(action, (signum,))
    for sig in signals:
        signal.signal(sig, handler)


class StopEvent(threading.Event):
    """A threading.Event whose waits wake every SIGNAL_CHECK_S, so that the main thread
    waiting on it runs a signal handler that another thread received (see above)."""

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            left = SIGNAL_CHECK_S if end is None else min(end - time.monotonic(), SIGNAL_CHECK_S)
            if super().wait(max(left, 0.0)):
                return True
            if end is not None and time.monotonic() >= end:
                return False


def stop_on_signals(signals: Iterable[int] = STOP_SIGNALS) -> threading.Event:
    """An event set by SIGTERM or SIGINT (Ctrl-C): how a program learns to stop."""
    stop = StopEvent()
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
