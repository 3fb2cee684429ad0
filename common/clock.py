"""The one clock every service reads, sleeps on and starts threads with.

On the car this is the wall clock: `monotonic()` is `time.monotonic()`, `Event()` is a
`threading.Event`, `Thread(...)` a `threading.Thread`. In the lockstep runner
(viena.common.lockstep) the same calls are answered by a virtual clock that jumps from
event to event, so the whole car runs in one process faster than real time and the same
seed gives the same bytes. A service does not know which clock it runs on: it imports
this module instead of `time`, `threading` and `queue` for anything that waits or reads
the time (ruff's banned-api rule in pyproject.toml keeps it so).

Which clock answers is decided per thread, at the call: a thread the virtual clock
started (or adopted) gets virtual time, every other thread gets the wall clock. A thread
of a library (canopen's notifier, zenoh's runtime) can never join a simulation by
accident, and lockstep tests and real-time tests can share a process.

The waiting objects raise the standard library's exceptions (`queue.Empty`,
`queue.Full`), so `except queue.Empty` reads the same on both clocks.
"""
from __future__ import annotations

import queue
import secrets
import threading
import time as _time
from collections.abc import Callable
from typing import Any, Protocol

Empty = queue.Empty
Full = queue.Full


class Clock(Protocol):
    """What a clock answers. `RealClock` is the car's; `VirtualClock` the runner's."""

    def monotonic_ns(self) -> int: ...
    def time_ns(self) -> int: ...
    def sleep(self, seconds: float) -> None: ...
    def event(self) -> Any: ...
    def queue(self, maxsize: int = 0) -> Any: ...
    def thread(self, target: Callable, name: str | None, args: tuple, kwargs: dict | None,
               daemon: bool) -> Any: ...
    def token_urlsafe(self, nbytes: int) -> str: ...


class RealClock:
    """The wall clock and the standard library's threads, as on the car."""

    monotonic_ns = staticmethod(_time.monotonic_ns)
    time_ns = staticmethod(_time.time_ns)
    sleep = staticmethod(_time.sleep)
    event = staticmethod(threading.Event)
    token_urlsafe = staticmethod(secrets.token_urlsafe)

    @staticmethod
    def queue(maxsize: int = 0) -> queue.Queue:
        return queue.Queue(maxsize)

    @staticmethod
    def thread(target: Callable, name: str | None, args: tuple, kwargs: dict | None,
               daemon: bool) -> threading.Thread:
        return threading.Thread(target=target, name=name, args=args, kwargs=kwargs, daemon=daemon)


REAL = RealClock()
#: thread ident -> the clock that thread lives on; absent means the wall clock
_CLOCK_OF_THREAD: dict[int, Any] = {}
# bound once: every call below runs on each read of the time (thousands a simulated second)
_clock_of = _CLOCK_OF_THREAD.get
_get_ident = threading.get_ident


def current() -> Any:
    """The clock of the calling thread."""
    return _clock_of(_get_ident(), REAL)


def adopt(clock: Any, ident: int | None = None) -> None:
    """Make a thread (default: the caller) live on `clock`; for clocks, not services."""
    _CLOCK_OF_THREAD[threading.get_ident() if ident is None else ident] = clock


def release(ident: int | None = None) -> None:
    """Give a thread (default: the caller) back to the wall clock."""
    _CLOCK_OF_THREAD.pop(threading.get_ident() if ident is None else ident, None)


def is_virtual() -> bool:
    """True on a thread of a virtual clock: for the few places that must not touch the
    real world there (signals, process exit)."""
    return current() is not REAL


# -- what services call ------------------------------------------------------------------------
def monotonic_ns() -> int:
    return _clock_of(_get_ident(), REAL).monotonic_ns()


def monotonic() -> float:
    return _clock_of(_get_ident(), REAL).monotonic_ns() / 1e9


def time_ns() -> int:
    """Nanoseconds since the Unix epoch (the virtual clock starts at a fixed date)."""
    return _clock_of(_get_ident(), REAL).time_ns()


def time() -> float:
    return _clock_of(_get_ident(), REAL).time_ns() / 1e9


def sleep(seconds: float) -> None:
    _clock_of(_get_ident(), REAL).sleep(seconds)


def token_urlsafe(nbytes: int = 16) -> str:
    """A secret token (a lease): unguessable on the car, the seed's own in a simulation,
    so two runs with one seed publish the same bytes."""
    return current().token_urlsafe(nbytes)


def Event() -> Any:  # noqa: N802 - a factory that stands for threading.Event
    """A `threading.Event`, or its virtual twin: `set`, `clear`, `is_set`, `wait(timeout)`."""
    return current().event()


def Queue(maxsize: int = 0) -> Any:  # noqa: N802 - a factory that stands for queue.Queue
    """A `queue.Queue`, or its virtual twin: `put`, `put_nowait`, `get(block, timeout)`,
    `get_nowait`, `qsize`, `empty`, `full`."""
    return current().queue(maxsize)


def Thread(target: Callable, name: str | None = None, args: tuple = (),  # noqa: N802
           kwargs: dict | None = None, daemon: bool = True) -> Any:
    """A `threading.Thread` (not yet started), or one the virtual clock schedules:
    `start`, `join(timeout)`, `is_alive`, `name`."""
    return current().thread(target, name, args, kwargs, daemon)
