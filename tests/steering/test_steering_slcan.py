"""The steering's own slcan bus (driver/slcan.py) on the twin's hub: the frames python-can's
slcan interface would send and receive, with reads in bulk and a period's frames in one write."""
from __future__ import annotations

import itertools

import can
import pytest

from viena.common import urlhandler
from viena.common.twin.slcan_hub import SlcanHub
from viena.services.steering.driver.slcan import SlcanBus

_n = itertools.count()


@pytest.fixture
def pair():
    hub = SlcanHub(f"steering-slcan-{next(_n)}").start()
    urlhandler.use()
    ours = SlcanBus(hub.url, sleep_after_open=0, timeout=0.01)
    theirs = can.Bus(interface="slcan", channel=hub.url, sleep_after_open=0, timeout=0.01)
    theirs.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
    assert _recv(ours).arbitration_id == 0x7FF              # both channels open on the hub
    yield ours, theirs
    ours.shutdown()
    theirs.shutdown()
    hub.stop()


def _recv(bus, timeout: float = 2.0) -> can.Message:
    msg = bus.recv(timeout)
    assert msg is not None
    return msg


def test_a_periods_frames_go_out_in_order(pair):
    ours, theirs = pair
    ours.send_frames([(0x764, b"\x05"), (0x201, bytes.fromhex("0f00e8030000")), (0x080, b"")])
    got = [_recv(theirs) for _ in range(3)]
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
        (0x764, b"\x05"), (0x201, bytes.fromhex("0f00e8030000")), (0x080, b"")]


def test_frames_come_in_whole_and_the_adapters_acks_are_skipped(pair):
    ours, theirs = pair
    ours.send_frames([(0x080, b"")])                       # the hub acknowledges: skipped
    sent = [can.Message(arbitration_id=0x181 + k, data=bytes([k, 1, 2, 3, 4, 5]), is_extended_id=False)
            for k in range(20)]
    sent.append(can.Message(arbitration_id=0x1ABCDEF, data=b"\x01\x02", is_extended_id=True))
    for msg in sent:
        theirs.send(msg)
    got = [_recv(ours) for _ in sent]
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got] == [
        (m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in sent]
    assert ours.recv(0.05) is None                          # nothing else: no ack became a frame


class _Port:
    """What an adapter sent, as a serial port serves it: all of it waiting at once."""

    def __init__(self, data: bytes):
        self.data = bytearray(data)

    def read(self, n: int) -> bytes:
        out = bytes(self.data[:n])
        del self.data[:n]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self.data)


def test_a_garbled_byte_spoils_its_line_and_not_the_bus():
    bus = SlcanBus.__new__(SlcanBus)                       # the reading half alone, on a port of bytes
    bus._buffer, bus.serialPortOrig = bytearray(), _Port(b"t18\xff\r\rt1812AB01\r")
    bus._queue = __import__("queue").Queue()
    assert bus._read(0.1) == "t18\ufffd\r"                  # python-can then refuses that line alone
    assert bus._read(0.1) == "\r"
    msg, _ = bus._recv_internal(0.1)
    assert (msg.arbitration_id, bytes(msg.data)) == (0x181, b"\xab\x01")


@pytest.mark.parametrize("garbled", [b"t18\xff\r", b"t1812A\xff01\r", b"t1G12AB01\r"])
def test_a_garbled_frame_is_skipped_by_the_receive_path_not_raised(garbled):
    """Raised, it would end python-can's receive thread and the link would count as lost."""
    bus = SlcanBus.__new__(SlcanBus)
    bus._buffer, bus.serialPortOrig = bytearray(), _Port(garbled + b"t1812AB01\r")
    bus._queue = __import__("queue").Queue()
    msg, _ = bus._recv_internal(0.1)
    assert (msg.arbitration_id, bytes(msg.data)) == (0x181, b"\xab\x01")


def test_an_slcan_adapters_receive_thread_wakes_100_times_a_second_when_idle_not_1000():
    """python-can's slcan port times out after 1 ms: its receive thread polled 1000 times a
    second whenever the bus was quiet, on the car's USB adapter too."""
    from viena.services.steering.driver.epos import _bus_options
    from viena.services.steering.model.drive import DriveSettings

    assert _bus_options(DriveSettings(interface="slcan", channel="/dev/ttyACM0"))["timeout"] == 0.01
    assert _bus_options(DriveSettings(interface="slcan", channel="/dev/ttyACM0",
                                      bus_options={"timeout": 0.05}))["timeout"] == 0.05
    assert "timeout" not in _bus_options(DriveSettings(interface="socketcan", channel="can0"))
