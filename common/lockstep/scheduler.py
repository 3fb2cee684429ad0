"""A virtual clock that runs real threads one at a time and jumps from event to event.

The services keep their threads: a GNSS reader, an estimator worker, the steering's control
loop. Under `VirtualClock` each of them is a real OS thread, but only the one holding the
baton runs. A thread gives the baton away only where it would wait on the car: in
`clock.sleep`, `Event.wait`, `Queue.get`/`put` and `Thread.join` (viena.common.clock). Then
the next ready thread runs, first come first served; when none is ready, time jumps to the
earliest deadline. Computing takes no virtual time. This is PX4 SITL's lockstep scheduler
and trio's MockClock with autojump, made deterministic: the order threads run in depends
only on the order they waited and woke, never on the OS, so the same inputs give the same
bytes.

The thread that creates the clock and calls `enter()` (a test, `viena sim run`) is the
driver: it runs the simulation by waiting (`run_for`, `run_until`), and is told when the
simulation deadlocks (everyone waits, nothing is due) or when a thread keeps the baton for
longer than `watchdog_s` of real time (a wait that bypassed the clock), with every
thread's stack.

Threads belong to a group (a program of the car). `kill(group)` is SIGKILL: its threads
never run again, nothing of theirs is cleaned up. `close()` ends the simulation and
unwinds every thread it still holds with `Killed`.

A handoff of the baton is an OS thread switch, and the car makes 1,400-1,800 a virtual
second. Two things make them cheaper (20 threads handing over: 10-23 us a switch on any
CPU, 8 on one, 4.3 on one as a batch): with `cpu` the simulation's threads all run on one
CPU, so a handoff never wakes a thread on another core only to wait there for the GIL; and
they run under Linux's SCHED_BATCH, so the thread given the baton does not preempt the one
handing it over while that one still holds the GIL (three context switches instead of
one). `cpu="auto"` takes a CPU no other simulation on this machine holds (a lock file per
CPU, let go at `close()` or when the process ends), or none if every one is taken. Both
are set on the driver at `enter()` (threads inherit them from the thread that starts
them) and taken back at `close()`; neither changes the order threads run in.
"""
from __future__ import annotations

import base64
import faulthandler
import heapq
import itertools
import logging
import os
import random
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from viena.common import clock as clocks

log = logging.getLogger(__name__)
_get_ident = threading.get_ident

#: where virtual monotonic time starts: far from 0, as a booted machine's is
START_NS = 1_000 * 1_000_000_000
#: the Unix time the simulation starts at (2026-01-01T00:00:00Z): fixed, so runs repeat
EPOCH_NS = 1_767_225_600 * 1_000_000_000


class Killed(BaseException):
    """Raised in a simulated thread to unwind it when the simulation closes. A
    BaseException, so a service's `except Exception` does not swallow it."""


class Deadlock(RuntimeError):
    """Every simulated thread waits and nothing is due: time cannot move."""


class Stuck(RuntimeError):
    """A simulated thread kept the baton for longer than the watchdog allows: it blocked
    outside the clock (a real lock, a socket) or loops without waiting."""


class _Task:
    """One simulated thread."""

    __slots__ = ("name", "group", "go", "woken", "parked", "wake_entry", "done", "killed", "ident", "error",
                 "unwound")

    def __init__(self, name: str, group: str):
        self.name, self.group = name, group
        # released when this task may run: a lock held from the start is the cheapest
        # one-shot signal between two threads (a Semaphore is a Condition in Python)
        self.go = threading.Lock()
        self.go.acquire()
        self.woken = False                # why the last park ended: woken (True) or timed out
        # waiting to be woken or to time out: once either has made it ready, the other must
        # not make it ready again (a task that timed out is still on its event's list until
        # it runs; a set() meanwhile would schedule it twice)
        self.parked = False
        self.wake_entry: _Entry | None = None
        self.done = False
        self.killed = False
        self.ident: int | None = None
        self.error: BaseException | None = None  # raised in the driver at its next park
        self.unwound: threading.Event | None = None  # set once close() has unwound it

    def __repr__(self) -> str:
        return f"<task {self.group}/{self.name}>"


class _Entry:
    """Something due at a time: a parked task's timeout, or a callback."""

    __slots__ = ("task", "callback", "cancelled")

    def __init__(self, task: _Task | None = None, callback: Callable[[], None] | None = None):
        self.task, self.callback, self.cancelled = task, callback, False

    def cancel(self) -> None:
        self.cancelled = True


class VirtualClock:
    """See the module docstring. `clock.monotonic()` and friends answer from here on the
    threads this clock runs."""

    def __init__(self, *, start_ns: int = START_NS, epoch_ns: int = EPOCH_NS, watchdog_s: float = 120.0,
                 realtime: float | None = None, seed: int = 0, cpu: int | str | None = None):
        self.now_ns = start_ns
        self.cpu = cpu                           # the one CPU every simulated thread runs on (None: any)
        self._driver_was: tuple[Any, ...] | None = None  # the driver's scheduling before enter()
        self._cpu_claim: Any = None              # the lock file that holds cpu="auto"'s CPU
        self._start_ns, self._epoch_ns = start_ns, epoch_ns
        self.watchdog_s = watchdog_s
        self.realtime = realtime
        self._ready: deque[_Task] = deque()
        self._heap: list[tuple[int, int, _Entry]] = []
        self._seq = itertools.count()
        self._tasks: dict[int, _Task] = {}       # by thread ident
        self._all: list[_Task] = []
        self._driver: _Task | None = None
        self._group = "driver"
        self._closing = False
        self._pace: tuple[float, int] | None = None  # (real monotonic, virtual ns) at the last anchor
        self.errors: list[tuple[str, BaseException]] = []  # (thread, exception) that ended a thread
        self.switches = 0
        self._tokens = random.Random(seed)

    # -- the clock interface (viena.common.clock) ----------------------------------------------
    def monotonic_ns(self) -> int:
        return self.now_ns

    def time_ns(self) -> int:
        return self._epoch_ns + self.now_ns - self._start_ns

    def sleep(self, seconds: float) -> None:
        me = self._me()
        if seconds <= 0:
            self._ready.append(me)     # let the others that are ready run first
            self._switch(me)
            self._raise_pending(me)
            return
        self._park(me, self.now_ns + round(seconds * 1e9))

    def token_urlsafe(self, nbytes: int) -> str:
        return base64.urlsafe_b64encode(self._tokens.randbytes(nbytes)).rstrip(b"=").decode()

    def event(self) -> VirtualEvent:
        return VirtualEvent(self)

    def queue(self, maxsize: int = 0) -> VirtualQueue:
        return VirtualQueue(self, maxsize)

    def thread(self, target: Callable, name: str | None, args: tuple, kwargs: dict | None,
               daemon: bool) -> VirtualThread:
        return VirtualThread(self, target, name, args, kwargs or {})

    # -- for the driver -----------------------------------------------------------------------
    def enter(self) -> None:
        """Make the calling thread this simulation's driver (the one that runs it)."""
        if self._driver is not None:
            raise RuntimeError("this clock has a driver already")
        task = _Task(threading.current_thread().name, "driver")
        task.ident = threading.get_ident()
        self._driver = task
        self._tasks[task.ident] = task
        self._all.append(task)
        clocks.adopt(self)
        cpu = self.cpu
        if cpu == "auto":
            cpu, self._cpu_claim = claim_cpu()
            self.cpu = cpu
        self._driver_was = _schedule_as_simulation(None if cpu is None else int(cpu))
        if self.realtime:
            self._pace = (time.monotonic(), self.now_ns)

    def __enter__(self) -> VirtualClock:
        self.enter()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def run_for(self, seconds: float) -> None:
        """Let the simulation run `seconds` of virtual time."""
        self.sleep(seconds)

    def run_for_ns(self, nanoseconds: int) -> None:
        """`run_for` to the nanosecond."""
        if nanoseconds > 0:
            self._park(self._me(), self.now_ns + nanoseconds)

    def run_until(self, condition: Callable[[], bool], within_s: float, step_s: float = 0.05) -> bool:
        """Run until `condition()` holds (checked every `step_s` of virtual time) or
        `within_s` have passed; says which."""
        end = self.now_ns + round(within_s * 1e9)
        while not condition():
            if self.now_ns >= end:
                return False
            self.sleep(min(step_s, (end - self.now_ns) / 1e9))
        return True

    @contextmanager
    def group(self, name: str) -> Iterator[None]:
        """Threads started inside belong to program `name` (threads they start, too)."""
        before, self._group = self._group, name
        try:
            yield
        finally:
            self._group = before

    def kill(self, group: str) -> int:
        """What SIGKILL does to a program: its threads never run again and nothing of
        theirs is cleaned up. Returns how many threads it stopped."""
        killed = 0
        for task in self._all:
            if task.group == group and not task.done and not task.killed:
                task.killed = True
                killed += 1
                if task.wake_entry is not None:
                    task.wake_entry.cancel()
        alive = [t for t in self._ready if not t.killed]
        self._ready.clear()             # in place: a callback of _next's may kill, and _next holds the deque
        self._ready.extend(alive)
        return killed

    def call_at(self, when_ns: int, callback: Callable[[], None]) -> _Entry:
        """Run `callback` at virtual time `when_ns`, on whichever thread moves time there.
        It must not wait. Returns a handle with `cancel()`."""
        entry = _Entry(callback=callback)
        heapq.heappush(self._heap, (max(when_ns, self.now_ns), next(self._seq), entry))
        return entry

    def threads(self) -> list[str]:
        """The simulated threads still alive, as group/name."""
        return [f"{t.group}/{t.name}" for t in self._all if not t.done and not t.killed]

    def close(self) -> None:
        """End the simulation: unwind every simulated thread (raising `Killed` where it
        waits), give the driver back to the wall clock."""
        if self._closing:
            return
        self._closing = True
        for task in self._all:
            if task is self._driver or task.done:
                continue
            task.unwound = threading.Event()
            task.go.release()
            if not task.unwound.wait(2.0):
                log.warning("simulated thread %r did not unwind", task)
        if self._driver is not None and self._driver.ident is not None:
            self._tasks.pop(self._driver.ident, None)
            clocks.release()
            self._driver.done = True
            _restore_scheduling(self._driver_was)
        if self._cpu_claim is not None:
            self._cpu_claim.close()              # the CPU is free for the next simulation
            self._cpu_claim = None

    # -- the scheduler ----------------------------------------------------------------------
    def _me(self) -> _Task:
        task = self._tasks.get(_get_ident())
        if task is None:
            raise RuntimeError("a virtual clock object was used from a thread the clock does not run")
        return task

    def _park(self, me: _Task, deadline_ns: int | None) -> bool:
        """Give the baton away until woken (True) or `deadline_ns` (False)."""
        if self._closing:
            raise Killed()
        me.woken = False
        me.parked = True
        if deadline_ns is not None:
            entry = _Entry(me)
            me.wake_entry = entry
            heapq.heappush(self._heap, (deadline_ns, next(self._seq), entry))
        # _switch inlined: a park is the runner's hottest path (1,300 a virtual second)
        nxt = self._next(me)
        if nxt is not me:
            self.switches += 1
            nxt.go.release()
            if me is self._driver:
                self._wait_for_baton(me)
            else:
                me.go.acquire()
        me.wake_entry = None
        if self._closing or me.error is not None:
            self._raise_pending(me)
        return me.woken

    def _raise_pending(self, me: _Task) -> None:
        if self._closing:
            raise Killed()
        if me.error is not None:
            error, me.error = me.error, None
            raise error

    def _wake(self, task: _Task) -> None:
        """Make a parked task ready (from the running thread: an Event set, a put)."""
        if not task.parked or task.killed or task.done:
            return
        task.parked = False
        task.woken = True
        if task.wake_entry is not None:
            task.wake_entry.cancel()
            task.wake_entry = None
        self._ready.append(task)

    def _switch(self, me: _Task) -> None:
        """Hand the baton to the next task and wait for it to come back."""
        nxt = self._next(me)
        if nxt is me:
            return
        self.switches += 1
        nxt.go.release()
        self._wait_for_baton(me)

    def _wait_for_baton(self, me: _Task) -> None:
        if me is not self._driver:
            me.go.acquire()
            return
        if not me.go.acquire(timeout=self.watchdog_s):
            print(f"virtual clock: no thread gave the baton back within {self.watchdog_s} s "
                  f"at t={self.now_ns / 1e9:.3f}; every thread:", file=sys.stderr, flush=True)
            faulthandler.dump_traceback(all_threads=True)
            self._closing = True      # two threads must never run on: whatever parks next unwinds
            raise Stuck(f"a simulated thread kept running for {self.watchdog_s} s of real time "
                        f"without waiting on the clock (stacks on stderr)")

    def _next(self, me: _Task) -> _Task:
        """The task to run next, moving time on (and running callbacks) while none is ready."""
        ready, heap = self._ready, self._heap
        while True:
            while ready:
                task = ready.popleft()
                if not task.killed and not task.done:
                    return task
            if not heap:
                return self._deadlock(me)
            when, _, entry = heapq.heappop(heap)
            if entry.cancelled:
                continue
            if when > self.now_ns:
                if self.realtime:
                    self._pace_to(when)
                self.now_ns = when
            sleeper = entry.task
            if sleeper is not None:
                sleeper.wake_entry = None
                if sleeper.parked and not sleeper.killed:
                    sleeper.parked = False
                    ready.append(sleeper)
            elif entry.callback is not None:
                try:
                    entry.callback()
                except Exception as exc:  # a twin's or a timer's fault: the run goes on, the test sees it
                    log.exception("callback at t=%.6f failed", when / 1e9)
                    self.errors.append(("callback", exc))

    def _deadlock(self, me: _Task) -> _Task:
        driver = self._driver
        waiting = ", ".join(self.threads())
        error = Deadlock(f"every simulated thread waits and nothing is due at t={self.now_ns / 1e9:.3f} "
                         f"({waiting})")
        if driver is None or driver.done:
            raise error
        driver.error = error
        driver.parked = False
        return driver

    def _pace_to(self, when_ns: int) -> None:
        if not self.realtime or self._pace is None:
            return
        real0, virtual0 = self._pace
        due = real0 + (when_ns - virtual0) / 1e9 / self.realtime
        late = due - time.monotonic()
        if late > 0:
            time.sleep(late)

    # -- threads (their lives: VirtualThread) -----------------------------------------------------
    def _spawn(self, thread: VirtualThread) -> _Task:
        """A task for `thread` in its creator's group (the driver's: the current group), ready
        to run on an OS thread of its own."""
        creator = self._me()
        task = _Task(thread.name, self._group if creator is self._driver else creator.group)
        self._all.append(task)
        real = threading.Thread(target=thread._live, args=(task,), name=thread.name, daemon=True)
        real.start()
        self._ready.append(task)
        return task

    def _hand_on(self, task: _Task) -> None:
        """Give the baton away for good: `task` has ended."""
        nxt = self._next(task)
        if nxt is not task:
            self.switches += 1
            nxt.go.release()


def claim_cpu() -> tuple[int | None, Any]:
    """A CPU of this process's that no other simulation on the machine has claimed, and the
    open lock file that claims it (an flock: the OS lets go of it when the process ends);
    (None, None) when every one is taken."""
    if not hasattr(os, "sched_getaffinity"):
        return None, None
    import fcntl
    import tempfile

    for cpu in sorted(os.sched_getaffinity(0), reverse=True):     # CPU 0 last: it takes most interrupts
        claim = open(os.path.join(tempfile.gettempdir(), f"viena-lockstep-cpu{cpu}.lock"), "a")  # noqa: SIM115
        try:
            fcntl.flock(claim, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            claim.close()
            continue
        return cpu, claim
    return None, None


def _schedule_as_simulation(cpu: int | None) -> tuple[Any, ...] | None:
    """Put the calling thread (and the threads it will start) on SCHED_BATCH, and on `cpu`
    if given; returns what to restore. Where the OS has neither, nothing changes."""
    if not hasattr(os, "sched_setscheduler"):
        return None
    was = (os.sched_getscheduler(0), os.sched_getparam(0), os.sched_getaffinity(0))
    try:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
    except OSError as exc:               # a container that refuses: slower, the same order
        log.warning("virtual clock: cannot schedule its threads as a batch on CPU %s: %s", cpu, exc)
    return was


def _restore_scheduling(was: tuple[Any, ...] | None) -> None:
    if was is None:
        return
    policy, param, affinity = was
    try:
        os.sched_setscheduler(0, policy, param)
        os.sched_setaffinity(0, affinity)
    except OSError as exc:
        log.warning("virtual clock: cannot restore the driver's scheduling: %s", exc)


class VirtualEvent:
    """`threading.Event` on the virtual clock."""

    def __init__(self, clock: VirtualClock):
        self._clock = clock
        self._flag = False
        self._waiters: list[_Task] = []

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        self._flag = True
        waiters, self._waiters = self._waiters, []
        for task in waiters:
            self._clock._wake(task)

    def clear(self) -> None:
        self._flag = False

    def wait(self, timeout: float | None = None) -> bool:
        if self._flag:
            return True
        if timeout is not None and timeout <= 0:
            return False
        clock = self._clock
        me = clock._me()
        self._waiters.append(me)
        deadline = None if timeout is None else clock.now_ns + round(timeout * 1e9)
        try:
            woken = clock._park(me, deadline)
        finally:
            if me in self._waiters:
                self._waiters.remove(me)
        return woken or self._flag


class VirtualQueue:
    """`queue.Queue` on the virtual clock (raises `queue.Empty` and `queue.Full`)."""

    def __init__(self, clock: VirtualClock, maxsize: int = 0):
        self._clock = clock
        self.maxsize = maxsize
        self._items: deque = deque()
        self._getters: deque[_Task] = deque()
        self._putters: deque[_Task] = deque()

    def qsize(self) -> int:
        return len(self._items)

    def empty(self) -> bool:
        return not self._items

    def full(self) -> bool:
        return 0 < self.maxsize <= len(self._items)

    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> None:
        if self.maxsize > 0 and len(self._items) >= self.maxsize:
            self._wait(self._putters, self.full, block, timeout, clocks.Full)
        self._items.append(item)
        if self._getters:       # (tested first: a put or get per delivery, most with no one waiting)
            self._wake_one(self._getters)

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        if not self._items:
            self._wait(self._getters, self.empty, block, timeout, clocks.Empty)
        item = self._items.popleft()
        if self._putters:
            self._wake_one(self._putters)
        return item

    def put_nowait(self, item: Any) -> None:
        self.put(item, block=False)

    def get_nowait(self) -> Any:
        return self.get(block=False)

    def _wait(self, waiters: deque[_Task], blocked: Callable[[], bool], block: bool, timeout: float | None,
              error: type[Exception]) -> None:
        clock = self._clock
        if not block or (timeout is not None and timeout <= 0):
            raise error()
        me = clock._me()
        deadline = None if timeout is None else clock.now_ns + round(timeout * 1e9)
        while blocked():
            if deadline is not None and clock.now_ns >= deadline:
                raise error()
            waiters.append(me)
            try:
                clock._park(me, deadline)
            finally:
                if me in waiters:
                    waiters.remove(me)

    def _wake_one(self, waiters: deque[_Task]) -> None:
        """Wake the first waiter still parked (one that timed out is on the list until it runs)."""
        while waiters:
            task = waiters.popleft()
            if task.parked:
                self._clock._wake(task)
                return


class VirtualThread:
    """`threading.Thread` on the virtual clock: scheduled by it from `start()`."""

    def __init__(self, clock: VirtualClock, target: Callable, name: str | None, args: tuple, kwargs: dict):
        self._clock = clock
        self._target, self._args, self._kwargs = target, args, kwargs
        self.name = name or f"vthread-{next(_names)}"
        self.daemon = True
        self._task: _Task | None = None
        self._finished = VirtualEvent(clock)

    def start(self) -> None:
        if self._task is not None:
            raise RuntimeError("threads can only be started once")
        self._task = self._clock._spawn(self)

    def _live(self, task: _Task) -> None:
        """The OS thread's whole life: wait for the baton, run the target (a failure is the
        clock's `errors`, a `Killed` the end of the simulation), then end."""
        clock = self._clock
        task.ident = threading.get_ident()
        clock._tasks[task.ident] = task
        clocks.adopt(clock)
        task.go.acquire()
        try:
            if clock._closing:
                raise Killed()
            self._target(*self._args, **self._kwargs)
        except Killed:
            pass
        except BaseException as exc:
            clock.errors.append((f"{task.group}/{task.name}", exc))
            log.exception("simulated thread %s/%s failed", task.group, task.name)
        finally:
            self._end(task)

    def _end(self, task: _Task) -> None:
        """Done: out of the clock's threads; joiners woken and the baton handed on, unless the
        simulation is closing (then close() waits for `unwound`)."""
        clock = self._clock
        task.done = True
        if task.ident is not None:
            clock._tasks.pop(task.ident, None)
        clocks.release()
        if clock._closing:
            if task.unwound is not None:
                task.unwound.set()
            return
        self._finished.set()
        clock._hand_on(task)

    def is_alive(self) -> bool:
        return self._task is not None and not self._task.done and not self._task.killed

    def join(self, timeout: float | None = None) -> None:
        if self._task is None:
            raise RuntimeError("cannot join thread before it is started")
        if self._task is self._clock._tasks.get(threading.get_ident()):
            raise RuntimeError("cannot join current thread")
        if self.is_alive():
            self._finished.wait(timeout)

    @property
    def ident(self) -> int | None:
        return self._task.ident if self._task else None


_names = itertools.count(1)
