"""The steering controller and the EPOS twin on a virtual CAN bus, on a simulated clock.

Nothing sleeps and the controller starts no thread: `step()` moves the clock one SYNC
period on, sends the twin's heartbeat when due, runs the controller's control step and its
blocking jobs in this thread, then waits (for readiness, not for time) until both ends have
handled every frame sent so far. The twin moves when the SYNC reaches it, at the simulated
time, so a test sees the same frames in the same order on every run.
"""
from __future__ import annotations

import itertools
import math
import threading

import canopen
import vienatest

from viena.services.steering.controller import ControllerSettings, SteeringController
from viena.services.steering.driver import DriveSettings, EposDrive
from viena.services.steering.model.calibration import CalibrationSettings
from viena.services.steering.model.safety import Envelope
from viena.services.steering.model.speed import SpeedSettings
from viena.services.steering.simulator.epos_twin import EposTwin, TwinSettings

#: a drive on a bench: no car, no speed source, and no speed assumed
ON_A_BENCH = SpeedSettings(speed_conservative_mps=0.0)

_channels = itertools.count()
WALL_NS_AT_0 = 1_700_000_000_000_000_000
FAST_SWEEP = TwinSettings(**vienatest.FAST_SWEEP)


class SimClock:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def wall_ns(self) -> int:
        return WALL_NS_AT_0 + round(self.t * 1e9)


class SimTimers:
    """canopen's periodic frames on `network` (the twin's heartbeat producer) sent on the
    simulated clock by `fire()` instead of by python-can's real-time thread."""

    def __init__(self, network: canopen.Network, clock: SimClock):
        self.network, self.clock = network, clock
        self.tasks: list[_Periodic] = []
        network.send_periodic = self.send_periodic

    def send_periodic(self, can_id: int, data, period: float, remote: bool = False) -> _Periodic:
        task = _Periodic(self, can_id, bytes(data), period, self.clock.t)
        self.tasks.append(task)
        return task

    def fire(self) -> None:
        for task in list(self.tasks):
            while task in self.tasks and task.due_t <= self.clock.t:
                self.network.send_message(task.can_id, task.data)
                task.due_t += task.period


class _Periodic:
    """What canopen's NmtSlave needs of a periodic task: stop() and update(data)."""

    def __init__(self, timers: SimTimers, can_id: int, data: bytes, period: float, due_t: float):
        self.timers, self.can_id, self.data, self.period, self.due_t = timers, can_id, data, period, due_t

    def stop(self) -> None:
        if self in self.timers.tasks:
            self.timers.tasks.remove(self)

    def update(self, data) -> None:
        self.data = bytes(data)


class Barrier:
    """Returns once both ends have handled every frame sent before it: a frame to the
    twin's network, echoed back to the drive's (each network handles frames in order)."""
    TO_TWIN, TO_DRIVE = 0x7F0, 0x7F1          # ids nothing else on this bus uses

    def __init__(self, twin_network: canopen.Network):
        self._done = threading.Event()
        self._drive_network = None
        twin_network.subscribe(self.TO_TWIN, lambda *_: twin_network.send_message(self.TO_DRIVE, b""))

    def wait(self, drive: EposDrive) -> None:
        network = drive.network
        if network is None:                       # the link is closed: nothing in flight
            return
        if network is not self._drive_network:    # opened again: a new network
            network.subscribe(self.TO_DRIVE, lambda *_: self._done.set())
            self._drive_network = network
        self._done.clear()
        network.send_message(self.TO_TWIN, b"")
        assert self._done.wait(5.0), "the virtual bus did not echo"


class SimSteering:
    """A SteeringController (no threads) driving the twin, both on one simulated clock."""

    def __init__(self, twin_settings: TwinSettings = FAST_SWEEP, **drive_kw):
        self.clock = SimClock()
        channel = f"sim-steering-{next(_channels)}"
        self.net = canopen.Network()
        self.net.NOTIFIER_CYCLE = 0.01  # how long closing waits for the receive thread
        self.net.connect(interface="virtual", channel=channel)
        self.timers = SimTimers(self.net, self.clock)
        self.barrier = Barrier(self.net)
        self.twin = EposTwin(self.net, twin_settings, clock=self.clock)
        self.twin.power_on()
        self.controlwords: list[int] = []
        self.net.subscribe(0x201, lambda _id, data, _t: self.controlwords.append(int.from_bytes(data[:2], "little")))
        self.states: list[dict] = []
        drive = EposDrive(DriveSettings(interface="virtual", channel=channel, **drive_kw), clock=self.clock)
        self.period_s = drive.settings.sync_period_s
        self.ctl = SteeringController(drive, Envelope(speed_settings=ON_A_BENCH), CalibrationSettings(sweep_settle_s=0.2), ControllerSettings(),
                                      on_state=self.states.append, clock=self.clock, wall_ns=self.clock.wall_ns)
        self.ctl.start(threads=False)

    # -- time ------------------------------------------------------------------------------
    def settle(self) -> None:
        """Let both ends handle what was sent, and do the blocking jobs that asked for."""
        self.barrier.wait(self.ctl.drive)
        self.ctl.run_jobs()

    def step(self) -> None:
        self.settle()
        self.clock.t += self.period_s
        self.timers.fire()
        self.ctl.control_step()
        self.settle()

    def run(self, seconds: float) -> None:
        for _ in range(max(1, round(seconds / self.period_s))):
            self.step()

    def run_until(self, condition, seconds: float) -> bool:
        """Step until condition() holds, for at most `seconds` of simulated time."""
        self.settle()
        end = self.clock.t + seconds
        while not condition():
            if self.clock.t >= end:
                return False
            self.step()
        return True

    # -- what a client does ----------------------------------------------------------------
    def request(self, kind: str, payload, seconds: float = 2.0) -> dict:
        """Ask, and step the clock until the answer comes (an arm's takes a few periods); a
        setpoint is signed with the lease it names, as a client sends it."""
        payload = vienatest.signed(payload) if kind == "setpoint" else payload
        box: list[dict] = []
        self.ctl.submit(kind, payload, box.append)
        assert self.run_until(lambda: bool(box), seconds), f"no answer to {kind} {payload}"
        return box[0]

    def ready(self, seconds: float = 10.0) -> None:
        assert self.run_until(lambda: self.ctl.phase == "ready", seconds), self.ctl.state()

    def arm(self) -> str:
        r = self.request("arm", {"arm": True})
        assert r["status"] == "accepted", r
        return r["lease"]

    def steer(self, lease: str, angle: float, seconds: float, rate: float = 50.0) -> list[dict]:
        replies = []
        for _ in range(int(seconds * rate)):
            replies.append(self.request("setpoint", {"angle_deg": angle, "lease": lease}))
            self.run(1 / rate)
        return replies

    def wheel_deg(self) -> float:
        return math.degrees(self.twin.wheel_angle_rad())

    def close(self) -> None:
        self.ctl.stop()
        self.twin.power_off()
        self.net.disconnect()
