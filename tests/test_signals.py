"""SIGTERM and Ctrl-C stop a program even when they come at the worst moment: while its
main thread, parked in `Event.wait()`, holds the event's lock on its way in or out
(viena.common.signals). A handler that set the event itself hung there for ever; once it
did so in CI, a GNSS twin that got SIGTERM right after saying READY."""
from __future__ import annotations

import subprocess
import sys

import pytest

#: a program whose SIGTERM comes while its main thread holds the stop event's lock, as
#: Event.wait() does on its way into and out of the wait
AT_THE_WORST_MOMENT = """
import os, signal
from viena.common.signals import stop_on_signals
stop = stop_on_signals()
with stop._cond:
    os.kill(os.getpid(), signal.SIGTERM)
    total = sum(range(1000))        # the handler runs between two of these bytecodes
print("stopped" if stop.wait(10) else "not stopped")
"""


def stops(program: str, hung: str) -> None:
    """Run `program`; it must print "stopped" and end, else fail with `hung`."""
    try:
        run = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=15)
    except subprocess.TimeoutExpired:
        pytest.fail(hung)
    assert (run.returncode, run.stdout.strip()) == (0, "stopped"), run.stderr


def test_a_signal_while_the_main_thread_holds_the_stop_events_lock_still_stops_the_program():
    stops(AT_THE_WORST_MOMENT, "the program hung in its signal handler")


#: a program whose SIGTERM the kernel hands to another of its threads (as it may to one
#: of zenoh's): Python only notes it there, and runs the handler in the main thread
ON_ANOTHER_THREAD = """
import signal, threading
from viena.common.signals import stop_on_signals
stop = stop_on_signals()
other = threading.Thread(target=lambda: signal.pthread_kill(threading.get_ident(), signal.SIGTERM))
threading.Timer(0.5, other.start).start()
print("stopped" if stop.wait() else "not stopped")
"""


def test_a_signal_another_thread_receives_still_stops_a_main_thread_waiting_without_end():
    """A `viena router` flooded just before ignored its SIGTERM so, in CI."""
    stops(ON_ANOTHER_THREAD, "the main thread never ran the handler")


class AskedWaits:
    """A stop event that records how long each wait was asked to take, and stops after `n`."""

    def __init__(self, n: int):
        self.asked: list[float] = []
        self.n = n

    def wait(self, timeout: float) -> bool:
        import time

        self.asked.append(timeout)
        time.sleep(timeout)
        return len(self.asked) >= self.n


def test_a_services_main_thread_never_waits_longer_than_the_signal_check():
    """A service's main thread sees a SIGTERM another thread received within SIGNAL_CHECK_S,
    not after a whole health period: its stop deadline (2 s, supervisor kills at 3) starts
    only once the handler runs."""
    from viena.common.service import HEALTH_PERIOD_S, Service
    from viena.common.signals import SIGNAL_CHECK_S

    service = Service.__new__(Service)            # only the loop: no settings, no session
    service.stopping = AskedWaits(n=6)
    published = list(service._health_periods())
    assert max(service.stopping.asked) <= SIGNAL_CHECK_S < HEALTH_PERIOD_S
    assert published                               # the first four waits add up to a health period
