"""A drive and its twin on a private python-can virtual bus, on a simulated clock.

The twin is not started as a thread: it moves when the host's SYNC (or a controlword)
arrives, at the simulated time, so following errors and heartbeat deadlines are exact.
"""
from __future__ import annotations

import itertools

import canopen
import pytest
from steering_helpers import SimClock

from viena.services.steering.driver import DriveSettings, EposDrive
from viena.services.steering.simulator.epos_twin import EposTwin, TwinSettings

_channels = itertools.count()


class Rig:
    """drive <-> twin; `run(seconds)` plays the host's control loop on the simulated clock."""

    def __init__(self, twin_settings: TwinSettings | None = None, **drive_kw):
        self.clock = SimClock()
        self.channel = f"steering-test-{next(_channels)}"
        self.net = canopen.Network()
        self.net.NOTIFIER_CYCLE = 0.01  # how long closing waits for the receive thread
        self.net.connect(interface="virtual", channel=self.channel)
        self.twin = EposTwin(self.net, twin_settings or TwinSettings(sweep=False), clock=self.clock)
        self.twin.power_on()
        self.drive = EposDrive(DriveSettings(interface="virtual", channel=self.channel, **drive_kw),
                               clock=self.clock)
        self.drive.open()

    def run(self, seconds: float, heartbeat: bool = True) -> None:
        """Advance by whole SYNC periods, each answered by the twin before the next."""
        period = self.drive.settings.sync_period_s
        for _ in range(max(1, round(seconds / period))):
            self.clock.t += period
            if heartbeat:
                seen = self.drive.feedback().count
                self.drive.cycle()
                assert self.drive.wait_feedback(lambda fb, seen=seen: fb.count >= seen + 2, 1.0), "no TPDO answer"
            else:
                self.twin.step()

    def enable(self) -> None:
        from viena.services.steering.driver import ds402
        hold = self.drive.feedback().position_qc
        self.drive.send_target(hold, ds402.CW_SHUTDOWN)
        self.run(0.01)
        self.drive.command(ds402.CW_ENABLE_OPERATION)
        self.run(0.01)
        assert self.drive.feedback().state == ds402.OPERATION_ENABLED

    def close(self) -> None:
        self.drive.close()
        self.twin.power_off()
        self.net.disconnect()


@pytest.fixture
def make_rig():
    """Rig(...) factory; every rig made is closed after the test."""
    rigs: list[Rig] = []

    def make(twin_settings: TwinSettings | None = None, **drive_kw) -> Rig:
        rigs.append(Rig(twin_settings, **drive_kw))
        return rigs[-1]
    yield make
    for r in rigs:
        r.close()


@pytest.fixture
def rig(make_rig):
    return make_rig()


@pytest.fixture
def configured(rig):
    rig.drive.configure(limits_qc=None)
    rig.run(0.05)
    return rig
