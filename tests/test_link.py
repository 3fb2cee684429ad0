"""The serial link over real transports: loop://, and socket:// to a device on a local TCP
port that vanishes and comes back; the reader thread that pushes its bytes; and the
supervisor keeping such a device going. Waits are on readiness, never fixed sleeps."""
from __future__ import annotations

import socket
import threading
import time

import pytest
import serial
from vienatest import wait_until

from viena.common.health import Health
from viena.common.link import SerialLink
from viena.common.link_reader import LinkReader
from viena.common.samples.health import CONNECT_FAILURES, CONNECTED, PORT_FAILURES, RECONNECTS
from viena.common.silence import SilenceWatch
from viena.common.supervisor import Backoff, Device, DeviceSupervisor

pytestmark = pytest.mark.timeout(60)


class TcpDevice:
    """A device behind socket://127.0.0.1:PORT: one host at a time; unplugging closes the
    connection and the listening socket, plugging in again listens on the same port."""

    def __init__(self, port: int = 0):
        self.server = socket.create_server(("127.0.0.1", port))
        self.port = self.server.getsockname()[1]
        self.conn: socket.socket | None = None
        self.connected = threading.Event()
        self.received = bytearray()
        threading.Thread(target=self._serve, daemon=True).start()

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def _serve(self) -> None:
        try:
            self.conn, _ = self.server.accept()
        except OSError:
            return
        self.connected.set()
        while True:
            try:
                data = self.conn.recv(4096)
            except OSError:
                return
            if not data:
                return
            self.received += data

    def send(self, data: bytes) -> None:
        assert self.connected.wait(10), "nobody opened the link"
        self.conn.sendall(data)

    def unplug(self) -> None:
        if self.conn is not None:
            self.conn.shutdown(socket.SHUT_RDWR)        # the FIN goes out though recv() waits
            self.conn.close()
        self.server.close()


def read_until(link: SerialLink, n: int, timeout_s: float = 10.0) -> bytes:
    got = b""
    end = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < end:
        got += link.read(0.05).data
    return got


def test_loop_round_trip_with_host_stamps():
    with SerialLink("loop://", 115200) as link:
        link.open()
        assert link.is_open and not link.carries_break
        before = time.time_ns()
        link.write(b"hello")
        got = read_until(link, 5)
        assert got == b"hello"
        chunk = link.read(0.0)
        assert chunk.data == b"" and before <= chunk.t_host_ns <= time.time_ns()
    assert not link.is_open


def test_the_link_knows_its_wire():
    assert SerialLink("/dev/ttyUSB0").carries_break
    assert SerialLink("rfc2217://10.0.0.2:4000").carries_break
    assert not SerialLink("socket://127.0.0.1:5000").carries_break
    assert SerialLink("loop://", 500_000).byte_time_s == pytest.approx(20e-6)


def test_a_closed_link_says_so():
    link = SerialLink("loop://")
    for use in (lambda: link.read(0.0), lambda: link.write(b"x"),
                lambda: link.set_baudrate(9600), lambda: link.send_break(0.25)):
        with pytest.raises(serial.PortNotOpenError):
            use()


def test_a_device_that_vanishes_fails_the_read_and_can_be_reopened_when_it_returns():
    device = TcpDevice()
    link = SerialLink(device.url)
    link.open()
    device.send(b"$GPGGA")
    assert read_until(link, 6) == b"$GPGGA"
    link.write(b"LOG BESTXYZ\r\n")
    assert wait_until(lambda: bytes(device.received) == b"LOG BESTXYZ\r\n", 10)

    device.unplug()
    with pytest.raises(serial.SerialException):
        read_until(link, 1)
    with pytest.raises(serial.SerialException):           # nobody listens now
        link.open()

    device = TcpDevice(device.port)                       # plugged back in
    link.open()
    device.send(b"again")
    assert read_until(link, 5) == b"again"
    link.close()
    device.unplug()


def test_the_reader_pushes_chunks_and_reports_a_lost_port_once():
    device = TcpDevice()
    link = SerialLink(device.url)
    got, errors = bytearray(), []
    lost = threading.Event()
    reader = LinkReader(link, lambda data, t: got.extend(data),
                        lambda exc: (errors.append(exc), lost.set()), name="test")
    link.open()
    reader.start()
    device.send(b"0123456789" * 100)
    assert wait_until(lambda: len(got) == 1000, 10)
    device.unplug()
    assert lost.wait(10)
    assert wait_until(lambda: not reader.running, 10)
    assert len(errors) == 1 and isinstance(errors[0], serial.SerialException)
    reader.stop()
    link.close()


def test_a_stopped_reader_reports_nothing_and_a_bad_consumer_does_not_end_it():
    device = TcpDevice()
    link = SerialLink(device.url)
    chunks, errors = [], []

    def consumer(data, t_host_ns):
        chunks.append(data)
        if len(chunks) == 1:
            raise ValueError("a consumer's bug")
    reader = LinkReader(link, consumer, errors.append)
    link.open()
    reader.start()
    device.send(b"first")
    assert wait_until(lambda: len(chunks) == 1, 10)
    device.send(b"second")
    assert wait_until(lambda: len(chunks) == 2, 10)
    reader.stop()
    assert not reader.running
    link.close()
    device.unplug()
    assert errors == []


class TickDevice(Device):
    """The smallest real device: a link whose every chunk is a sign of life."""

    kind = "tick device"

    def __init__(self, url: str, silence: SilenceWatch):
        self.link, self.silence = SerialLink(url), silence
        self.received = bytearray()

    def connect(self, again: bool) -> None:
        self.link.open()

    def serve(self, timeout_s: float) -> None:
        data, t_host_ns = self.link.read(timeout_s)
        if data:
            self.silence.heard(t_host_ns)
            self.received += data

    def disconnect(self) -> None:
        self.link.close()


def say_until_heard(device: TcpDevice, tick: TickDevice, word: bytes) -> bool:
    """Repeat `word` until the host has it: pyserial drops what arrives while it opens."""
    return wait_until(lambda: word in tick.received or device.send(word), 10, period=0.02)


def test_the_supervisor_reconnects_a_device_that_vanishes_and_returns():
    device = TcpDevice()
    silence = SilenceWatch(5.0)
    health = Health("test", "tick0")
    tick = TickDevice(device.url, silence)
    supervisor = DeviceSupervisor(tick, health, silence, url=device.url,
                                  backoff=Backoff(0.01, 0.05), tick_s=0.05).start()
    try:
        assert say_until_heard(device, tick, b"one")
        device.unplug()
        assert wait_until(lambda: health.errors()[CONNECT_FAILURES] >= 2, 10)
        assert health.errors()[PORT_FAILURES] == 1 and health.counts()[RECONNECTS] == 0
        assert health.snapshot()["state"][CONNECTED] is False

        device = TcpDevice(device.port)
        assert say_until_heard(device, tick, b"two")
        assert health.counts()[RECONNECTS] == 1
        assert health.snapshot()["state"][CONNECTED] is True
    finally:
        supervisor.stop()
        device.unplug()
    assert not tick.link.is_open
