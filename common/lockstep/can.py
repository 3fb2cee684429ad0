"""A python-can interface whose wire and timers live on viena.common.clock, so canopen (the
steering's drive and the EPOS twin) runs on the lockstep runner's virtual clock.

    register()                                            # or the `can.interface` entry point
    bus = can.Bus(interface="lockstep", channel="steering")

Buses opened with the same channel share one wire, as python-can's `virtual` does: a frame
reaches every other bus of the channel (and its sender with `receive_own_messages`), stamped
with `clock.time()` when sent. What differs is who delivers it. python-can's `virtual` fills
a queue that a `can.Notifier` thread drains with `bus.recv(timeout)`, on the wall clock and
on a thread the virtual clock does not run. Here each bus has its own dispatcher, a
`clock.Thread` draining a `clock.Queue`, which calls the listeners of the Notifiers attached
to the bus (`can.Notifier.find_instances`) itself, as the Notifier would. The Notifier's own
thread is left with nothing to do: `recv()` parks it on a real condition and always answers
None, and stopping the Notifier wakes it, so `network.disconnect()` does not wait for it.
`recv()` therefore never returns a frame: listen through a Notifier.

Periodic frames (`send_periodic`: canopen's heartbeat producer, SYNC and PDO timers) are
sent by a clock thread that waits the period on a clock Event, and canopen's SDO client
waits for answers on a clock Queue (`install_canopen_clock`, which opening a bus does).
On the wall clock all this behaves as `virtual` does; every bus of a channel must live on
the clock of the thread that opened the first one.
"""
from __future__ import annotations

import logging
import queue
import threading
import weakref
from collections.abc import Callable, Sequence
from types import SimpleNamespace
from typing import Any

import can
import can.interfaces
import can.util
from can.broadcastmanager import (
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)
from can.typechecking import Channel

from viena.common import clock as clocks

log = logging.getLogger(__name__)

INTERFACE = "lockstep"

#: clock -> channel -> the open buses on it (each simulation its own wires, gone with its
#: clock); a channel's tuple is replaced whole on each change, so senders read it unlocked
_wires: weakref.WeakKeyDictionary[Any, dict[Channel, tuple[LockstepBus, ...]]] = weakref.WeakKeyDictionary()
_channels_lock = threading.Lock()


def _channels_of(clock: Any) -> dict[Channel, tuple[LockstepBus, ...]]:
    with _channels_lock:
        return _wires.setdefault(clock, {})


class LockstepBus(can.BusABC):
    """One node's connection to an in-process CAN channel, delivered on the clock that
    opened it. Accepts and ignores the arguments of other interfaces (bitrate, ...)."""

    def __init__(self, channel: Channel = "lockstep", receive_own_messages: bool = False,
                 can_filters: can.typechecking.CanFilters | None = None, **kwargs: Any):
        install_canopen_clock()
        self._clock = clocks.current()
        self.channel_id = channel
        self.channel_info = f"lockstep channel {channel}"
        self.receive_own_messages = receive_own_messages
        self._open = True
        self._inbox = clocks.Queue()
        # where foreign threads that call recv() (a Notifier's) park; _wakeups releases them
        self._parked = threading.Condition()
        self._wakeups = 0
        self._hooked: weakref.WeakSet[can.Notifier] = weakref.WeakSet()
        self._failed: weakref.WeakSet[can.Notifier] = weakref.WeakSet()
        self._known: tuple[can.Notifier, ...] = ()    # the Notifiers the last frame found, all hooked
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._channels = _channels_of(self._clock)
        with _channels_lock:
            peers = self._channels.get(channel, ())
            self._dispatcher = clocks.Thread(self._dispatch, name=f"lockstep-can {channel}")
            self._dispatcher.start()
            self._channels[channel] = (*peers, self)

    # -- the wire ------------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue a copy of `msg` for every other bus of the channel; never waits."""
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        if clocks.current() is not self._clock:
            raise can.CanOperationError(f"{self.channel_info}: sent from a thread of another clock")
        timestamp = clocks.time()
        for bus in self._channels.get(self.channel_id, ()):
            if bus is self and not self.receive_own_messages:
                continue
            if not bus._dispatcher.is_alive():      # its program was killed: a node without power
                continue
            bus._inbox.put(can.Message(          # a copy with its own bytes, as the sender's may change
                timestamp=timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, channel=self.channel_id,
                dlc=msg.dlc, data=bytearray(msg.data), is_fd=msg.is_fd, is_rx=bus is not self,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator))

    def _dispatch(self) -> None:
        while True:
            msg = self._inbox.get()
            if msg is None:
                return
            if self._filters is None or self._matches_filters(msg):
                self._deliver(msg)

    def _deliver(self, msg: can.Message) -> None:
        """What `Notifier._rx_thread` does with a frame, for every Notifier of this bus."""
        notifiers = can.Notifier.find_instances(self)
        if notifiers != self._known:         # a Notifier came or went (the WeakSets are slow to ask per frame)
            for notifier in notifiers:
                if notifier not in self._hooked:
                    self._hook(notifier)
            self._known = notifiers
        for notifier in notifiers:
            if notifier.stopped or (self._failed and notifier in self._failed):
                continue
            try:
                for listener in list(notifier.listeners):
                    listener(msg)
            except Exception as exc:
                self._listener_failed(notifier, exc)

    def _listener_failed(self, notifier: can.Notifier, exc: Exception) -> None:
        """As a Notifier: keep the error for `network.check()`, offer it to the listeners'
        `on_error`; unhandled, that Notifier hears nothing more (its thread would die)."""
        notifier.exception = exc
        handled = False
        for listener in list(notifier.listeners):
            on_error = getattr(listener, "on_error", None)
            if on_error is not None:
                try:
                    on_error(exc)
                    handled = True
                except NotImplementedError:
                    pass
        if not handled:
            log.error("%s: a listener failed, its notifier stops hearing", self.channel_info, exc_info=exc)
            self._failed.add(notifier)

    # -- what a Notifier's own thread sees ----------------------------------------------------------
    def recv(self, timeout: float | None = None) -> can.Message | None:
        """Park the caller (a Notifier's thread, on the wall clock) until its Notifier
        stops, the bus shuts down or `timeout` passes: the dispatcher delivers instead."""
        for notifier in can.Notifier.find_instances(self):
            if notifier not in self._hooked:
                self._hook(notifier)
        with self._parked:
            seen = self._wakeups
            self._parked.wait_for(lambda: self._wakeups != seen, timeout)
        return None

    def _hook(self, notifier: can.Notifier) -> None:
        """Make the Notifier's stop() wake its parked thread instead of joining it for up to
        its timeout, 1 s by default (python-can wraps a periodic task's stop() the same way)."""
        with self._parked:
            if notifier in self._hooked:     # the other thread was first
                return
            self._hooked.add(notifier)
        stop = notifier.stop

        def stop_without_waiting(timeout: float = 5.0) -> None:
            stop(timeout=0)          # flags it stopped, stops its listeners; nothing to join
            self._wake_parked()

        notifier.stop = stop_without_waiting  # type: ignore[method-assign]  # this one instance stops at once

    def _wake_parked(self) -> None:
        with self._parked:
            self._wakeups += 1
            self._parked.notify_all()

    # -- periodic frames and life -----------------------------------------------------------------
    def _send_periodic_internal(self, msgs: Sequence[can.Message] | can.Message, period: float,
                                duration: float | None = None, autostart: bool = True,
                                modifier_callback: Callable[[can.Message], None] | None = None,
                                ) -> LockstepCyclicSendTask:
        return LockstepCyclicSendTask(self, msgs, period, duration, autostart, modifier_callback)

    def shutdown(self) -> None:
        if self._open:
            self.stop_all_periodic_tasks()          # first: none of them finds the bus closed
            self._open = False
            with _channels_lock:
                rest = tuple(b for b in self._channels.get(self.channel_id, ()) if b is not self)
                if rest:
                    self._channels[self.channel_id] = rest
                else:
                    self._channels.pop(self.channel_id, None)
            self._wake_parked()
            if clocks.current() is self._clock:     # (not from the garbage collector's thread)
                self._inbox.put(None)
                if self._dispatcher.ident != threading.get_ident():
                    self._dispatcher.join(1.0)
        super().shutdown()


class LockstepCyclicSendTask(LimitedDurationCyclicSendTaskABC, ModifiableCyclicTaskABC,
                             RestartableCyclicTaskABC):
    """python-can's ThreadBasedCyclicSendTask on viena.common.clock: a clock thread sends
    each period (due times kept, not drifting) and waits on a clock Event that stop() sets.
    `modify_data` (canopen's `PeriodicMessageTask.update`) swaps the frames in place."""

    def __init__(self, bus: LockstepBus, messages: Sequence[can.Message] | can.Message, period: float,
                 duration: float | None = None, autostart: bool = True,
                 modifier_callback: Callable[[can.Message], None] | None = None):
        if period <= 0:
            raise ValueError(f"a period of {period} s")
        super().__init__(messages, period, duration)
        self.bus = bus
        self.modifier_callback = modifier_callback
        self.thread: Any = None
        self._stop: Any = None          # the clock Event of the running thread
        if autostart:
            self.start()

    def start(self) -> None:
        if self._stop is not None and not self._stop.is_set():
            return
        self._stop = clocks.Event()
        self.end_time = clocks.monotonic() + self.duration if self.duration else None
        self.thread = clocks.Thread(self._run, name=f"lockstep-can periodic 0x{self.arbitration_id:X}",
                                    args=(self._stop,))
        self.thread.start()

    def stop(self) -> None:
        if self._stop is not None:
            self._stop.set()

    def _run(self, stop: Any) -> None:
        index = 0
        due_ns = clocks.monotonic_ns()
        while not stop.is_set():
            if self.end_time is not None and clocks.monotonic() >= self.end_time:
                stop.set()
                return
            msg = self.messages[index]
            try:
                if self.modifier_callback is not None:
                    self.modifier_callback(msg)
                self.bus.send(msg)
            except can.CanError as exc:
                log.warning("periodic 0x%X stops: %s", self.arbitration_id, exc)
                stop.set()
                return
            index = (index + 1) % len(self.messages)
            due_ns += self.period_ns
            stop.wait(max(0, due_ns - clocks.monotonic_ns()) / 1e9)


# -- canopen and python-can ------------------------------------------------------------------------
#: what canopen's SDO client and LSS master find as their modules `queue` and `time`
_CANOPEN_QUEUE = SimpleNamespace(Queue=clocks.Queue, Empty=queue.Empty)
_CANOPEN_TIME = SimpleNamespace(time=clocks.time, sleep=clocks.sleep, monotonic=clocks.monotonic)


def install_canopen_clock() -> None:
    """Make canopen's SDO client (and LSS master) wait for answers on viena.common.clock:
    their `queue.Queue().get(timeout=RESPONSE_TIMEOUT)` and `time.sleep` become the clock's.
    The wall clock's on every thread but the runner's, so harmless on the car; idempotent.
    Takes effect for clients made afterwards: a LockstepBus calls it when opened, and
    `EposDrive.open` connects its network before it adds the node."""
    import canopen.lss
    import canopen.sdo.client

    for module in (canopen.sdo.client, canopen.lss):
        setattr(module, "queue", _CANOPEN_QUEUE)  # noqa: B010 - typed modules, plain attributes
        setattr(module, "time", _CANOPEN_TIME)  # noqa: B010


def register() -> None:
    """Make `can.Bus(interface="lockstep")` resolve without the `can.interface` entry point
    (python-can reads entry points into BACKENDS and VALID_INTERFACES when imported)."""
    can.interfaces.BACKENDS.setdefault(INTERFACE, (__name__, LockstepBus.__name__))
    if INTERFACE not in can.util.VALID_INTERFACES:
        valid = can.util.VALID_INTERFACES | {INTERFACE}
        can.util.VALID_INTERFACES = can.interfaces.VALID_INTERFACES = can.VALID_INTERFACES = valid
