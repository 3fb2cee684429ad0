"""The device supervisor and the silence watch on a simulated clock: the backoff between
attempts, reconnecting after the device vanishes and returns, silence (fixed, and following
the device's epochs), bugs that must neither stop nor spin, counters in health. No
threads and no sleeping, except where `stop()` itself is the subject."""
from __future__ import annotations

import threading

import pytest

from viena.common.health import Health
from viena.common.samples.health import (
    CONNECT_FAILURES,
    CONNECTED,
    DEVICE_ERRORS,
    INTERNAL_ERRORS,
    LAST_ERROR,
    PORT,
    PORT_FAILURES,
    RECONNECTS,
    SILENCES,
)
from viena.common.silence import SilenceWatch
from viena.common.supervisor import Backoff, Device, DeviceSupervisor

T0_NS = 1_700_000_000_000_000_000
STEP_S = 0.01


class SimTime:
    """The host clock, moved by the test: the supervisor's waits and the device's
    serving advance it."""

    def __init__(self):
        self.now_ns = T0_NS

    def __call__(self) -> int:
        return self.now_ns

    @property
    def t_s(self) -> float:
        return (self.now_ns - T0_NS) / 1e9

    def advance(self, seconds: float) -> None:
        self.now_ns += round(seconds * 1e9)


class SimStopping(threading.Event):
    """The supervisor's `stopping`: its waits pass simulated time at once and are noted."""

    def __init__(self, clock: SimTime):
        super().__init__()
        self.clock = clock
        self.waits: list[float] = []

    def wait(self, timeout=None) -> bool:
        self.waits.append(timeout)
        self.clock.advance(timeout)
        return self.is_set()


class ScriptedDevice(Device):
    """A device whose life is a script in simulated seconds: plugged in except during
    `absent` intervals; says something every `period_s` except during `mute` intervals
    (reconnecting ends a mute: the device was reconfigured). A sign of life is an epoch
    with `marks_epochs`. The test ends at `end_s`."""

    kind = "scripted device"

    def __init__(self, clock: SimTime, stopping: threading.Event, silence: SilenceWatch, *,
                 end_s: float, absent=(), mute=(), period_s: float = 0.05,
                 marks_epochs: bool = False):
        self.clock, self.stopping, self.silence = clock, stopping, silence
        self.end_s, self.absent, self.mute = end_s, list(absent), list(mute)
        self.period_s, self.marks_epochs = period_s, marks_epochs
        self.attempts: list[tuple[float, bool]] = []      # (time, again)
        self.connected_at: list[float] = []
        self.open = False
        self.shut_down = False
        self.frames = 0
        self.heard_at: list[float] = []
        self._next_frame_s = 0.0

    def _during(self, intervals) -> bool:
        return any(a <= self.clock.t_s < b for a, b in intervals)

    def connect(self, again: bool) -> None:
        self.attempts.append((self.clock.t_s, again))
        if self._during(self.absent):
            raise OSError("no such device")
        self.open = True
        self.connected_at.append(self.clock.t_s)
        self.mute = [(a, b) for a, b in self.mute if b <= self.clock.t_s or a > self.clock.t_s]
        self._next_frame_s = self.clock.t_s

    def serve(self, timeout_s: float) -> None:
        end = self.clock.t_s + timeout_s
        while self.clock.t_s < end - 1e-9:
            self.clock.advance(STEP_S)
            if self.clock.t_s >= self.end_s:
                self.stopping.set()
                return
            if self._during(self.absent):
                raise OSError("device disconnected")
            if self.clock.t_s >= self._next_frame_s and not self._during(self.mute):
                self._next_frame_s += self.period_s
                self.frames += 1
                self.heard_at.append(self.clock.t_s)
                (self.silence.epoch if self.marks_epochs else self.silence.heard)(self.clock())

    def disconnect(self) -> None:
        self.open = False

    def shutdown(self) -> None:
        self.shut_down = True
        self.disconnect()

    def counters(self):
        return {"frames": self.frames}, {"crc_errors": self.frames // 10}


def supervised(silence_s: float = 1.0, epochs: float | None = None, max_s: float = 0.5,
               **script):
    clock = SimTime()
    stopping = SimStopping(clock)
    silence = SilenceWatch(silence_s, epochs=epochs, clock=clock)
    device = ScriptedDevice(clock, stopping, silence, **script)
    health = Health("test", "unit0")
    supervisor = DeviceSupervisor(device, health, silence, url="socket://127.0.0.1:9",
                                  backoff=Backoff(0.05, max_s), tick_s=0.1, stopping=stopping)
    return supervisor, device, health, stopping


def test_backoff_doubles_from_the_first_wait_up_to_the_cap_and_starts_over():
    backoff = Backoff(0.05, 0.5)
    assert [backoff.next_s() for _ in range(7)] == [0.05, 0.1, 0.2, 0.4, 0.5, 0.5, 0.5]
    backoff.reset()
    assert backoff.next_s() == 0.05
    assert [Backoff(0.05, 0.01).next_s() for _ in range(3)] == [0.01] * 3


def test_the_device_is_reconnected_after_it_vanishes_and_returns():
    supervisor, device, health, stopping = supervised(
        end_s=10.0, absent=[(0.0, 2.0), (5.0, 6.0)])
    supervisor.run()

    attempts = [t for t, _ in device.attempts]
    # absent at start: at once, then after 0.05, 0.1, 0.2, 0.4 and at most 0.5 s
    assert attempts[:8] == pytest.approx([0.0, 0.05, 0.15, 0.35, 0.75, 1.25, 1.75, 2.25])
    # lost at 5.0: tried again at once, and the backoff starts over from 0.05 s
    assert attempts[8:] == pytest.approx([5.0, 5.05, 5.15, 5.35, 5.75, 6.25])
    assert [again for _, again in device.attempts] == [False] * 8 + [True] * 6
    assert max(stopping.waits) == 0.5
    assert device.connected_at == pytest.approx([2.25, 6.25])

    counts, errors, state = health.counts(), health.errors(), health.snapshot()["state"]
    assert counts[RECONNECTS] == 1
    assert errors[CONNECT_FAILURES] == 12 and errors[PORT_FAILURES] == 1
    assert errors[SILENCES] == errors[INTERNAL_ERRORS] == 0
    assert state[LAST_ERROR] == "no such device" and state[CONNECTED] is False
    assert device.shut_down and not device.open


def test_the_counters_are_shown_from_the_start_and_reach_health_as_increments():
    supervisor, device, health, _ = supervised(end_s=3.0)
    assert health.counts() == {RECONNECTS: 0, "frames": 0}
    assert health.errors() == {**{name: 0 for name in DEVICE_ERRORS}, "crc_errors": 0}
    assert health.snapshot()["state"] == {PORT: "socket://127.0.0.1:9", CONNECTED: False}
    supervisor.run()
    assert device.frames > 50
    assert health.counts()["frames"] == device.frames
    assert health.errors()["crc_errors"] == device.frames // 10


def test_a_silent_device_is_reopened_once_the_silence_timeout_has_passed():
    supervisor, device, health, _ = supervised(end_s=8.0, mute=[(3.0, 99.0)])
    supervisor.run()
    assert health.errors()[SILENCES] == 1 and health.counts()[RECONNECTS] == 1
    # noticed at the first 0.1 s tick after 1 s without a frame
    [_, again_at] = device.connected_at
    last_s = max(t for t in device.heard_at if t < again_at)
    assert last_s + 1.0 < again_at <= last_s + 1.0 + 0.1 + STEP_S
    assert health.snapshot()["state"][LAST_ERROR].startswith("silent for 1.")


def test_a_device_that_keeps_talking_is_never_declared_silent():
    supervisor, device, health, _ = supervised(end_s=30.0, period_s=0.9)
    supervisor.run()
    assert health.errors()[SILENCES] == 0 and device.connected_at == [0.0]


@pytest.mark.parametrize("follow_epochs, silent", [(None, True), (3.0, False)])
def test_a_1_hz_receiver_is_silent_only_under_a_fixed_timeout(follow_epochs, silent):
    """Issue 12's receiver: epochs 1.06 s apart. A fixed 1 s timeout declares it silent;
    one that follows its epochs (3 x the median interval, at least 1 s) does not."""
    supervisor, device, health, _ = supervised(end_s=60.0, period_s=1.06, marks_epochs=True,
                                               epochs=follow_epochs)
    supervisor.run()
    assert (health.errors()[SILENCES] > 0) is silent


def test_a_bug_in_the_device_is_counted_and_waits_before_reopening():
    supervisor, device, health, stopping = supervised(end_s=5.0, max_s=0.4)
    real_serve = device.serve
    calls = []

    def buggy(timeout_s):
        calls.append(timeout_s)
        if len(calls) == 3:
            raise KeyError("a bug")
        real_serve(timeout_s)
    device.serve = buggy
    supervisor.run()
    assert health.errors()[INTERNAL_ERRORS] == 1 and health.counts()[RECONNECTS] == 1
    assert stopping.waits == [0.4]                   # not at once: a bug must not spin
    assert device.connected_at == pytest.approx([0.0, 0.2 + 0.4])
    assert "KeyError" in health.snapshot()["state"][LAST_ERROR]


def test_a_port_closed_by_stop_is_not_counted_as_a_failure():
    supervisor, device, health, stopping = supervised(end_s=99.0)

    def closed_under_it(timeout_s):
        stopping.set()
        raise OSError("port closed")
    device.serve = closed_under_it
    supervisor.run()
    assert health.errors()[PORT_FAILURES] == 0 and device.shut_down


def test_stop_closes_a_device_stuck_in_connect():
    class Stuck(Device):
        def __init__(self):
            self.entered, self.released = threading.Event(), threading.Event()

        def connect(self, again):
            self.entered.set()
            if self.released.wait(10):
                raise OSError("closed while connecting")

        def serve(self, timeout_s):
            raise AssertionError("never connected")

        def disconnect(self):
            self.released.set()

    device = Stuck()
    health = Health("test")
    supervisor = DeviceSupervisor(device, health, SilenceWatch(1.0), url="loop://").start()
    assert device.entered.wait(10)
    supervisor.stop(join_s=0.05)
    assert device.released.is_set() and not supervisor._thread.is_alive()
    assert health.errors()[CONNECT_FAILURES] == 0          # stopping is not a failure


class TestSilenceWatch:
    def make(self, **kw):
        clock = SimTime()
        return clock, SilenceWatch(1.0, clock=clock, **kw)

    def test_quiet_counts_from_the_last_sign_of_life(self):
        clock, watch = self.make()
        clock.advance(0.6)
        watch.heard()
        clock.advance(0.9)
        assert watch.quiet_s() == pytest.approx(0.9) and not watch.expired()
        clock.advance(0.2)
        assert watch.expired()
        watch.heard(clock() - 1_500_000_000)           # a stamp older than the last one
        assert watch.quiet_s() == pytest.approx(1.1)
        watch.restart()
        assert watch.quiet_s() == 0 and not watch.expired()

    def test_the_timeout_follows_the_median_epoch_interval_but_never_drops_below_the_floor(self):
        clock, watch = self.make(epochs=3.0)
        assert watch.timeout_s == 1.0                  # nothing measured yet
        for _ in range(10):
            clock.advance(1.06)
            watch.epoch()
        assert watch.timeout_s == pytest.approx(3.18)
        clock.advance(2.5)
        assert not watch.expired()
        clock.advance(0.8)
        assert watch.expired()
        fast_clock, fast = self.make(epochs=3.0)
        for _ in range(40):
            fast_clock.advance(0.05)
            fast.epoch()
        assert fast.timeout_s == 1.0

    def test_one_long_gap_does_not_move_the_median_and_a_reconnection_is_not_a_gap(self):
        clock, watch = self.make(epochs=3.0)
        for _ in range(10):
            clock.advance(0.5)
            watch.epoch()
        clock.advance(4.0)                             # one late epoch
        watch.epoch()
        assert watch.timeout_s == pytest.approx(1.5)
        watch.restart()
        clock.advance(60.0)                            # the device was away: not its pace
        watch.epoch()
        clock.advance(0.5)
        watch.epoch()
        assert watch.timeout_s == pytest.approx(1.5)
