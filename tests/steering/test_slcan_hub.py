"""The slcan hub as python-can's own `slcan` interface sees it, and as a raw socket does."""
from __future__ import annotations

import itertools
import socket
import threading
import time

import can
import pytest
from vienatest import wait_until

from viena.common.twin.slcan_hub import SlcanHub, _Client, format_frame, parse_frame

_n = itertools.count()


@pytest.fixture
def hub():
    h = SlcanHub(f"hub-test-{next(_n)}").start()
    yield h
    h.stop()


@pytest.fixture
def buses():
    opened = []

    def open_(*args, **kw) -> can.BusABC:
        kw.setdefault("sleep_after_open", 0)
        opened.append(can.Bus(*args, **kw))
        return opened[-1]
    yield open_
    # pyserial's socket:// close waits 0.3 s "for quick reconnects": close them together
    closing = [threading.Thread(target=b.shutdown) for b in opened]
    for t in closing:
        t.start()
    for t in closing:
        t.join()


def opened(*slcan_buses) -> None:
    """Until the hub has handled each bus's opening commands: it answers a client's
    commands in order, so its answer to `V` comes after them."""
    for bus in slcan_buses:
        assert bus.get_version(2.0) == (10, 13)


def recv_all(bus, expect: int = 0, quiet_s: float = 0.1) -> list:
    """The frames that reach `bus`: up to 2 s for the `expect`ed ones, then `quiet_s`
    in which any that should not come would show."""
    out = []
    for seconds, enough in ((2.0, lambda: len(out) >= expect), (quiet_s, lambda: False)):
        end = time.monotonic() + seconds
        while not enough() and time.monotonic() < end:
            m = bus.recv(0.01)
            if m is not None:
                out.append(m)
    return out


def test_python_can_slcan_opens_it_like_an_adapter(hub, buses):
    bus = buses(interface="slcan", channel=hub.url, bitrate=1_000_000)
    assert bus.get_version(1.0) == (10, 13)
    assert bus.get_serial_number(1.0) == "VIEN"


def test_frames_reach_every_other_node_but_not_their_sender(hub, buses):
    a = buses(interface="slcan", channel=hub.url, bitrate=1_000_000)
    b = buses(interface="slcan", channel=hub.url, bitrate=1_000_000)
    sim = buses(interface="virtual", channel=hub.channel)
    opened(a, b)
    a.send(can.Message(arbitration_id=0x181, data=b"\x01\x02\x03", is_extended_id=False))
    a.send(can.Message(arbitration_id=0x1ABCDE, data=b"\xff" * 8, is_extended_id=True))
    a.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False))
    for rx in (b, sim):
        got = recv_all(rx, expect=3)
        assert [(m.arbitration_id, m.is_extended_id, m.is_remote_frame, bytes(m.data)) for m in got] == [
            (0x181, False, False, b"\x01\x02\x03"), (0x1ABCDE, True, False, b"\xff" * 8), (0x701, False, True, b"")]
    assert recv_all(a) == []
    sim.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
    assert [m.arbitration_id for m in recv_all(a, 1)] == [0x80] == [m.arbitration_id for m in recv_all(b, 1)]


def test_listen_only_hears_but_cannot_talk_and_a_wrong_bitrate_hears_nothing(hub, buses):
    listener = buses(interface="slcan", channel=hub.url, listen_only=True)
    deaf = buses(interface="slcan", channel=hub.url, bitrate=500_000)
    sim = buses(interface="virtual", channel=hub.channel)
    opened(listener, deaf)
    listener.send(can.Message(arbitration_id=0x123, data=b"\x00", is_extended_id=False))
    deaf.send(can.Message(arbitration_id=0x124, data=b"\x00", is_extended_id=False))
    opened(listener, deaf)                             # the hub has handled both frames
    assert recv_all(sim) == []
    sim.send(can.Message(arbitration_id=0x181, data=b"\x05", is_extended_id=False))
    assert [m.arbitration_id for m in recv_all(listener, 1)] == [0x181]
    assert recv_all(deaf) == []


def raw_client(hub):
    s = socket.create_connection((hub.host, hub.port), timeout=1.0)
    return s


def ask(s, text: bytes, expect: int) -> bytes:
    s.sendall(text)
    out = b""
    end = time.monotonic() + 1.0
    while out.count(b"\r") + out.count(b"\a") < expect and time.monotonic() < end:
        out += s.recv(100)
    return out


def test_commands_are_answered_as_lawicel_does(hub):
    with raw_client(hub) as s:
        assert ask(s, b"V\r", 1) == b"V1013\r"
        assert ask(s, b"S8\r", 1) == b"\r"
        assert ask(s, b"t1230\r", 1) == b"\a"             # channel closed: no frames
        assert ask(s, b"O\r", 1) == b"\r"
        assert ask(s, b"S6\r", 1) == b"\a"                # no bitrate change while open
        assert ask(s, b"t12321122\r", 1) == b"z\r"
        assert ask(s, b"T00000181180\r", 1) == b"Z\r"
        assert ask(s, b"t12391122\r", 1) == b"\a"          # dlc 9
        assert ask(s, b"t1232112\r", 1) == b"\a"           # one nibble short
        assert ask(s, b"tXYZ0\r", 1) == b"\a"
        assert ask(s, b"?\r", 1) == b"\a"
        assert ask(s, b"x" * 100, 1) == b"\a"              # no CR at all: resync
        assert ask(s, b"\rF\r", 2) == b"\rF00\r"
        assert ask(s, b"C\r", 1) == b"\r"


def test_a_client_that_vanishes_does_not_disturb_the_others(hub, buses):
    a = buses(interface="slcan", channel=hub.url)
    with raw_client(hub) as s:
        ask(s, b"O\r", 1)
    opened(a)
    wait_until(lambda: hub.clients == 1, 2.0)          # the hub saw the other one go
    sim = buses(interface="virtual", channel=hub.channel)
    sim.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
    assert [m.arbitration_id for m in recv_all(a, 1)] == [0x181]
    assert hub.clients == 1


def test_frame_text_round_trips():
    for msg in (can.Message(arbitration_id=0x7FF, data=b"\x00\x10", is_extended_id=False),
                can.Message(arbitration_id=0x1FFFFFFF, data=b"", is_extended_id=True),
                can.Message(arbitration_id=0x80, is_remote_frame=True, dlc=3, is_extended_id=False)):
        back = parse_frame(format_frame(msg).decode()[:-1])
        assert (back.arbitration_id, back.is_extended_id, back.is_remote_frame, back.dlc, bytes(back.data)) == \
            (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc, bytes(msg.data))
    assert format_frame(can.Message(arbitration_id=0x12, data=b"\xab", is_extended_id=False), 61_000) == b"t0121AB03E8\r"


def test_a_frame_is_acknowledged_before_the_frames_that_answer_it(hub, buses):
    sim = buses(interface="virtual", channel=hub.channel)
    answers = [can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False),
               can.Message(arbitration_id=0x281, data=b"\x03", is_extended_id=False)]

    def answer_sync() -> None:
        if (m := sim.recv(2.0)) is not None and m.arbitration_id == 0x080:
            for a in answers:
                sim.send(a)
    drive = threading.Thread(target=answer_sync)
    with raw_client(hub) as s:
        assert ask(s, b"O\r", 1) == b"\r"
        drive.start()
        assert ask(s, b"t0800\r", 3) == b"z\r" + b"".join(format_frame(a) for a in answers)
    drive.join()


class _Writes:
    """A client's socket that keeps each write."""

    def __init__(self):
        self.writes: list[bytes] = []

    def sendall(self, data: bytes) -> None:
        self.writes.append(bytes(data))

    def close(self) -> None:
        pass


def test_what_a_client_is_owed_at_one_moment_goes_in_one_write():
    hub = SlcanHub(f"hub-writes-{next(_n)}")           # not started: its two threads' steps by hand
    try:
        client = _Client(_Writes(), ("127.0.0.1", 0), hub.bitrate)
        client.open = True
        hub._clients.append(client)
        tpdos = [can.Message(arbitration_id=0x181 + 0x100 * k, data=bytes([k] * 6), is_extended_id=False)
                 for k in range(2)]
        hub._send(client, b"z\rz\rz\r", hold=True)      # a period's frames acknowledged: held a USB frame
        assert client.sock.writes == []
        hub._to_clients(tpdos, exclude=None)            # the drive's answers to the SYNC
        assert client.sock.writes == [b"z\rz\rz\r" + b"".join(format_frame(m) for m in tpdos)]
        hub._send(client, b"z\r", hold=True)            # nothing answers: it goes on its own

        def flushed() -> bool:
            hub._flush_owed()                           # the serving thread's step
            return client.sock.writes[-1] == b"z\r"
        assert wait_until(flushed, 1.0)
        assert len(client.sock.writes) == 2 and not client.owed
    finally:
        hub.stop()
