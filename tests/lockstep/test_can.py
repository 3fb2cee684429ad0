"""The lockstep CAN interface on the wall clock: a shared wire per channel, delivery by the
bus's own clock thread (canopen's Notifier thread idles), periodic frames on clock threads,
and the steering's drive configuring and following the EPOS twin over it."""
from __future__ import annotations

import itertools
import threading

import can
import canopen
import pytest
from vienatest import wait_until

from viena.common import clock
from viena.common.lockstep import can as lockstep_can
from viena.services.steering.driver import DriveSettings, EposDrive, ds402
from viena.services.steering.simulator.epos_twin import EposTwin, TwinSettings

_channels = itertools.count()
MARK = 0x7FF


@pytest.fixture
def channel():
    lockstep_can.register()
    return f"lockstep-test-{next(_channels)}"


def frame(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def until_mark(reader: can.BufferedReader) -> list[can.Message]:
    """What `reader` hears up to the MARK frame (which every test sends last)."""
    heard = []
    while (msg := reader.get_message(5.0)) is not None and msg.arbitration_id != MARK:
        heard.append(msg)
    assert msg is not None, "the mark never came"
    return heard


def test_a_frame_reaches_every_other_bus_of_its_channel(channel):
    a, b = (can.Bus(interface="lockstep", channel=channel) for _ in range(2))
    c = can.Bus(interface="lockstep", channel=channel, receive_own_messages=True)
    elsewhere = can.Bus(interface="lockstep", channel=channel + "-elsewhere")
    buses = (a, b, c, elsewhere)
    readers = [can.BufferedReader() for _ in buses]
    notifiers = [can.Notifier(bus, [reader]) for bus, reader in zip(buses, readers)]
    try:
        sent = frame(0x101, b"\x01")
        a.send(sent)
        sent.data[0] = 9                                 # the wire has its own copy
        b.send(frame(0x102, b"\x02"))
        c.send(frame(MARK))
        heard = [[(m.arbitration_id, bytes(m.data)) for m in until_mark(r)] for r in readers[:3]]
        assert heard == [[(0x102, b"\x02")], [(0x101, b"\x01")], [(0x101, b"\x01"), (0x102, b"\x02")]]
        c.send(frame(0x103))
        c.send(frame(MARK))
        own = until_mark(readers[2])
        assert [(m.arbitration_id, m.is_rx, m.channel) for m in own] == [(0x103, False, channel)]
        assert own[0].timestamp > 1e9                    # Unix time, as python-can's buses stamp
        assert readers[3].get_message(0) is None        # another channel: another wire
    finally:
        for notifier in notifiers:
            notifier.stop()
        for bus in buses:
            bus.shutdown()


def test_canopen_hears_on_the_bus_thread_and_its_notifier_thread_idles(channel):
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 3600.0       # a notifier thread that ever woke by itself would show
    net.connect(interface="lockstep", channel=channel)
    peer = can.Bus(interface="lockstep", channel=channel)
    threads = []
    net.subscribe(0x181, lambda *_: threads.append(threading.current_thread().name))
    peer.send(frame(0x181, b"\x00"))
    assert wait_until(lambda: threads, 5.0)
    assert threads == [f"lockstep-can {channel}"]
    bus, reader = net.bus, net.notifier._readers[0]
    assert reader.is_alive()
    net.disconnect()                  # stops the notifier: its thread is woken, not joined
    reader.join(5.0)
    assert not reader.is_alive()
    with pytest.raises(can.CanOperationError):
        bus.send(frame(0x181))
    peer.shutdown()


def test_canopen_waits_for_sdo_answers_on_the_clock():
    lockstep_can.install_canopen_clock()
    lockstep_can.install_canopen_clock()
    assert canopen.sdo.client.queue.Queue is clock.Queue and canopen.sdo.client.time.sleep is clock.sleep


def test_periodic_frames_repeat_change_and_stop(channel):
    net = canopen.Network()
    net.connect(interface="lockstep", channel=channel)
    listener = can.Bus(interface="lockstep", channel=channel)
    reader = can.BufferedReader()
    notifier = can.Notifier(listener, [reader])
    try:
        task = net.send_periodic(0x701, b"\x7f", 0.005)          # canopen's heartbeat producer
        assert [reader.get_message(5.0).data for _ in range(3)] == [b"\x7f"] * 3
        task.update(b"\x05")                                      # python-can's modify_data
        assert wait_until(lambda: (m := reader.get_message(1.0)) is not None and m.data == b"\x05", 5.0)
        task.stop()
        task._task.thread.join(5.0)
        assert not task._task.thread.is_alive()
        brief = net.bus.send_periodic(frame(0x702), 0.005, duration=0.02)
        brief.thread.join(5.0)
        assert not brief.thread.is_alive()
        endless = net.bus.send_periodic(frame(0x703), 0.005)
        net.disconnect()                                          # the bus's shutdown stops its tasks
        endless.thread.join(5.0)
        assert not endless.thread.is_alive()
    finally:
        notifier.stop()
        listener.shutdown()


def test_the_drive_configures_and_follows_the_twin(channel):
    twin_net = canopen.Network()
    twin_net.connect(interface="lockstep", channel=channel)
    twin = EposTwin(twin_net, TwinSettings(sweep=False))
    twin.power_on()
    drive = EposDrive(DriveSettings(interface="lockstep", channel=channel))
    drive.open()
    try:
        drive.configure()                                                    # by SDO
        assert drive.read(0x6065) == 7500 and drive.read(0x1017) == 100
        assert ds402.state_of(drive.read(0x6041)) == ds402.SWITCH_ON_DISABLED
        assert wait_until(lambda: drive.heartbeat_age() < 1.0, 5.0)          # the twin's periodic heartbeat
        drive.send_target(drive.feedback().position_qc, ds402.CW_SHUTDOWN)  # RPDO
        drive.cycle()                                                        # SYNC: TPDOs back
        assert drive.wait_feedback(lambda fb: fb.state == ds402.READY and fb.op_mode == -1, 5.0)
    finally:
        drive.close()
        twin.power_off()
        twin_net.disconnect()
