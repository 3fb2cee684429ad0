"""Who may open a device twin's port (issue 24, item 7): a serial twin has one host at a
time, so no process takes the line over from the service, while the service's own
reconnect always gets in; on this machine only processes of the twin's own user are served
(common/twin/peers.py), by the serial twins and the slcan hub alike."""
from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from vienatest import wait_until

from viena.common.twin import peers
from viena.common.twin.peers import peer_uid, refusal
from viena.common.twin.serial_port import ByteTwin, SerialEndpoint
from viena.common.twin.slcan_hub import SlcanHub

pytestmark = pytest.mark.timeout(60)
SYSTEM_PYTHON = Path("/usr/bin/python3")        # readable by any user, unlike a venv under /root


class Echo(ByteTwin):
    """Says back what it hears; counts the hosts that opened it."""

    def __init__(self):
        self.connects, self.out = 0, bytearray()

    def on_connect(self, now_s: float) -> None:
        self.connects += 1

    def feed(self, data: bytes, now_s: float) -> None:
        self.out += data

    def poll(self, now_s: float) -> bytes:
        out, self.out = bytes(self.out), bytearray()
        return out


@pytest.fixture
def echo():
    twin = Echo()
    endpoint = SerialEndpoint(twin, name="echo").start()
    yield twin, endpoint
    endpoint.stop()


def connect(endpoint) -> socket.socket:
    return socket.create_connection((endpoint.host, endpoint.port), timeout=5.0)


def closed_by_the_twin(sock: socket.socket) -> bool:
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


def echoes(sock: socket.socket) -> bool:
    sock.sendall(b"ping")
    got = b""
    while len(got) < 4:
        chunk = sock.recv(4 - len(got))
        if not chunk:
            return False
        got += chunk
    return got == b"ping"


def test_a_serial_twin_refuses_a_second_host_and_keeps_the_first(echo, caplog):
    twin, endpoint = echo
    with connect(endpoint) as first:
        assert wait_until(lambda: twin.connects == 1, 5.0)
        with connect(endpoint) as second:
            assert closed_by_the_twin(second)
        assert endpoint.refused == 1 and twin.connects == 1
        assert echoes(first)                              # the line is still the first host's
        assert "echo: connection refused: another host holds the line" in caplog.text
    with connect(endpoint) as third:                      # the first gone, the line is free
        assert wait_until(lambda: twin.connects == 2, 5.0)
        assert echoes(third)


def test_a_host_that_closed_its_end_gets_back_in_at_once(echo):
    """A service reconnecting closes, then opens: never refused, however quick."""
    twin, endpoint = echo
    sock = connect(endpoint)
    for n in range(1, 21):
        assert wait_until(lambda n=n: twin.connects == n, 5.0)
        sock.close()
        sock = connect(endpoint)
    assert wait_until(lambda: twin.connects == 21, 5.0) and echoes(sock)
    sock.close()
    assert endpoint.refused == 0


def test_the_other_end_of_a_connection_is_this_user():
    server = socket.create_server(("127.0.0.1", 0))
    with server, socket.create_connection(server.getsockname()) as client:
        conn, _ = server.accept()
        with conn:
            assert peer_uid(conn) == os.getuid() and refusal(conn) is None
            assert peer_uid(client) == os.getuid()        # either end


def test_another_users_process_is_refused(echo, monkeypatch, caplog):
    """Another uid at the other end (as the kernel would say it): closed unserved, by a
    serial twin and by the slcan hub, with one line each."""
    twin, endpoint = echo
    monkeypatch.setattr(peers, "peer_uid", lambda conn: os.getuid() + 1)
    with connect(endpoint) as sock:
        assert closed_by_the_twin(sock)
    assert endpoint.refused == 1 and twin.connects == 0
    with SlcanHub("twin-ports-test") as hub:
        with socket.create_connection((hub.host, hub.port), timeout=5.0) as sock:
            assert closed_by_the_twin(sock)
        assert hub.refused == 1 and hub.clients == 0
    assert f"a process of uid {os.getuid() + 1}, not {os.getuid()}" in caplog.text


@pytest.mark.skipif(os.getuid() != 0 or not SYSTEM_PYTHON.exists() or not sys.platform.startswith("linux"),
                    reason="needs root, to run a process as another user")
def test_a_real_other_user_is_refused_and_the_own_user_served(echo, caplog):
    caplog.set_level(logging.INFO)
    twin, endpoint = echo
    with SlcanHub("twin-ports-real") as hub:
        for host, port in ((endpoint.host, endpoint.port), (hub.host, hub.port)):
            probe = (f"import socket; s = socket.create_connection(({host!r}, {port}), timeout=5); "
                     f"s.sendall(b'V\\r'); print(repr(s.recv(16)))")
            other = subprocess.run([SYSTEM_PYTHON, "-c", probe], user=65534, capture_output=True, text=True, timeout=20)
            assert other.stdout.strip() in ("b''", ""), other         # closed unserved (or reset)
        assert endpoint.refused == 1 and hub.refused == 1 and twin.connects == 0
        with socket.create_connection((hub.host, hub.port), timeout=5.0) as own:
            own.sendall(b"V\r")
            assert own.recv(16) == b"V1013\r"
    assert "a process of uid 65534" in caplog.text
