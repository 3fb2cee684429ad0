"""The virtual clock: real threads, one at a time, time jumping from event to event."""
from __future__ import annotations

import os
import queue
import threading
import time

import pytest

from viena.common import clock
from viena.common.lockstep.scheduler import START_NS, Deadlock, Stuck, VirtualClock


@pytest.fixture
def vc():
    with VirtualClock(watchdog_s=5.0) as vc:
        yield vc


def test_sleeps_end_in_time_order_and_take_no_real_time(vc):
    seen = []

    def sleeper(name, seconds):
        for _ in range(3):
            clock.sleep(seconds)
            seen.append((name, round(clock.monotonic() - START_NS / 1e9, 3)))

    for name, seconds in (("slow", 2.5), ("fast", 1.0)):
        clock.Thread(sleeper, name=name, args=(name, seconds)).start()
    real0 = time.monotonic()
    vc.run_for(10)
    assert time.monotonic() - real0 < 2.0        # 10 s of virtual time, not of the wall's
    assert seen == [("fast", 1.0), ("fast", 2.0), ("slow", 2.5), ("fast", 3.0), ("slow", 5.0), ("slow", 7.5)]
    assert vc.errors == []


def test_the_clock_is_per_thread(vc):
    assert clock.monotonic_ns() == START_NS
    real = []
    foreign = threading.Thread(target=lambda: real.append(clock.monotonic_ns()))
    foreign.start()
    foreign.join()
    assert abs(real[0] - time.monotonic_ns()) < 1e9  # a thread the clock does not run: the wall clock
    assert clock.Event().__class__.__name__ == "VirtualEvent"


def test_wall_time_starts_at_a_fixed_date(vc):
    t0 = clock.time_ns()
    vc.run_for(1.5)
    assert clock.time_ns() - t0 == 1_500_000_000
    assert time.gmtime(t0 / 1e9)[:3] == (2026, 1, 1)


def test_event_wakes_its_waiter_at_the_setters_time_or_times_out(vc):
    event, results = clock.Event(), []

    def waiter(timeout):
        results.append((timeout, event.wait(timeout), clock.monotonic_ns() - START_NS))

    clock.Thread(waiter, args=(0.5,)).start()
    clock.Thread(waiter, args=(5.0,)).start()
    vc.run_for(2.0)
    event.set()
    vc.run_for(0.1)
    assert results == [(0.5, False, 500_000_000), (5.0, True, 2_000_000_000)]
    assert event.wait(0) is True


def test_queue_hands_items_over_in_order_with_timeouts_and_a_bound(vc):
    q, got = clock.Queue(maxsize=2), []

    def producer():
        for i in range(5):
            q.put(i)                       # blocks at two waiting
            got.append(("put", i, clock.monotonic_ns() - START_NS))

    def consumer():
        clock.sleep(1.0)
        while True:
            try:
                got.append(("get", q.get(timeout=0.25), clock.monotonic_ns() - START_NS))
            except queue.Empty:
                got.append(("empty", None, clock.monotonic_ns() - START_NS))
                return

    clock.Thread(producer).start()
    clock.Thread(consumer).start()
    vc.run_for(3)
    assert [g for g in got if g[0] == "get"] == [("get", i, 1_000_000_000) for i in range(5)]
    assert got[-1] == ("empty", None, 1_250_000_000)
    assert [g[1] for g in got if g[0] == "put"] == [0, 1, 2, 3, 4]
    with pytest.raises(queue.Empty):
        q.get_nowait()


def test_join_waits_for_the_thread_and_groups_are_inherited(vc):
    def child():
        clock.sleep(1)

    def parent():
        t = clock.Thread(child, name="child")
        t.start()
        t.join()
        marks.append(clock.monotonic_ns() - START_NS)
        clock.sleep(100)

    marks: list[int] = []
    with vc.group("program"):
        clock.Thread(parent, name="parent").start()
    vc.run_for(2)
    assert marks == [1_000_000_000]
    assert vc.threads() == ["driver/MainThread", "program/parent"]


def test_a_deadlock_is_reported_to_the_driver_with_who_waits(vc):
    clock.Thread(lambda: clock.Event().wait(), name="forever").start()
    with pytest.raises(Deadlock, match="forever"):
        clock.Event().wait()


def test_kill_stops_a_program_and_close_unwinds_the_rest():
    ticks = {"a": 0, "b": 0}
    unwound = []

    def ticker(name):
        try:
            while True:
                clock.sleep(0.1)
                ticks[name] += 1
        finally:
            unwound.append(name)

    vc = VirtualClock()
    vc.enter()
    for name in ticks:
        with vc.group(name):
            clock.Thread(ticker, args=(name,)).start()
    vc.run_for(1.05)
    assert ticks == {"a": 10, "b": 10}
    assert vc.kill("a") == 1
    vc.run_for(1.0)
    assert ticks == {"a": 10, "b": 20}
    assert unwound == []                      # SIGKILL: nothing ran on the way out
    vc.close()
    assert sorted(unwound) == ["a", "b"]      # closing unwinds every thread it still holds
    assert clock.current() is clock.REAL


def test_a_thread_that_blocks_outside_the_clock_is_reported_not_hung():
    gate = threading.Event()
    vc = VirtualClock(watchdog_s=0.3)
    vc.enter()
    try:
        clock.Thread(gate.wait, name="bypass").start()
        with pytest.raises(Stuck):
            vc.run_for(1)
    finally:
        gate.set()
        vc.close()


def test_a_failing_thread_is_recorded_and_the_run_goes_on(vc):
    def boom():
        clock.sleep(0.1)
        raise ValueError("boom")

    clock.Thread(boom, name="boom").start()
    vc.run_for(1)
    assert [(who, str(exc)) for who, exc in vc.errors] == [("driver/boom", "boom")]


def test_callbacks_run_at_their_time_without_a_thread(vc):
    at = []
    vc.call_at(START_NS + 300_000_000, lambda: at.append(clock.monotonic_ns() - START_NS))
    cancelled = vc.call_at(START_NS + 200_000_000, lambda: at.append("cancelled"))
    cancelled.cancel()
    vc.run_for(1)
    assert at == [300_000_000]


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux's scheduling calls")
def test_its_threads_run_as_a_batch_on_the_cpu_given_and_the_driver_gets_its_own_back():
    cpu = max(os.sched_getaffinity(0))
    before = (os.sched_getscheduler(0), os.sched_getaffinity(0))
    seen = []
    with VirtualClock(cpu=cpu) as vc:
        clock.Thread(lambda: seen.append((os.sched_getscheduler(0), os.sched_getaffinity(0)))).start()
        vc.run_for(1)
    assert seen == [(os.SCHED_BATCH, {cpu})]
    assert (os.sched_getscheduler(0), os.sched_getaffinity(0)) == before


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux's scheduling calls")
def test_simulations_that_run_at_once_take_cpus_of_their_own_and_give_them_back():
    import fcntl
    import tempfile

    with VirtualClock(cpu="auto") as one, VirtualClock(cpu="auto") as other:
        claimed = [vc.cpu for vc in (one, other) if vc.cpu is not None]    # None: every CPU was taken
        assert len(set(claimed)) == len(claimed)
    for cpu in claimed:
        with open(os.path.join(tempfile.gettempdir(), f"viena-lockstep-cpu{cpu}.lock"), "a") as claim:
            fcntl.flock(claim, fcntl.LOCK_EX | fcntl.LOCK_NB)           # free again: no BlockingIOError


def test_realtime_pacing_follows_the_wall_clock():
    with VirtualClock(realtime=4.0) as vc:
        real0 = time.monotonic()
        vc.run_for(0.4)
        assert time.monotonic() - real0 >= 0.09


def _busy_world(seed: int) -> list:
    """Threads that talk through queues and events with seed-dependent timings."""
    import random

    rng = random.Random(seed)
    log: list = []
    q, ev = clock.Queue(), clock.Event()

    def worker(i, periods):
        for p in periods:
            clock.sleep(p)
            q.put((i, clock.monotonic_ns()))
            if i == 0:
                ev.set()

    def sink():
        while True:
            log.append(q.get())

    def watcher():
        while True:
            if ev.wait(0.07):
                ev.clear()
                log.append(("ev", clock.monotonic_ns()))

    for i in range(4):
        clock.Thread(worker, args=(i, [rng.choice((0.01, 0.02, 0.05)) for _ in range(50)])).start()
    clock.Thread(sink).start()
    clock.Thread(watcher).start()
    return log


def test_the_same_inputs_give_the_same_order():
    runs = []
    for _ in range(2):
        with VirtualClock() as vc:
            log = _busy_world(7)
            vc.run_for(5)
            runs.append(list(log))
    assert len(runs[0]) > 200
    assert runs[0] == runs[1]
