"""viena's `socket://` port (common/urlhandler): pyserial's read semantics, in whole reads."""
from __future__ import annotations

import socket
import threading

import pytest
import serial
from vienatest import wait_until

from viena.common import urlhandler
from viena.common.urlhandler import protocol_socket


@pytest.fixture
def link():
    """(port, the peer's socket): a `socket://` port opened through pyserial's URL lookup."""
    urlhandler.use()
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = serial.serial_for_url(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.2)
        peer, _ = server.accept()
    yield port, peer
    port.close()
    peer.close()


def test_socket_urls_open_the_chunked_port(link):
    port, _ = link
    assert isinstance(port, protocol_socket.Serial)
    assert serial.protocol_handler_packages.count("viena.common.urlhandler") == 1
    urlhandler.use()                                   # twice changes nothing
    assert serial.protocol_handler_packages.count("viena.common.urlhandler") == 1


def test_reads_come_from_one_receive_in_pieces(link):
    port, peer = link
    peer.sendall(b"t1818\r")
    assert port.read(1) == b"t"                        # waits for the first bytes
    assert port.in_waiting == 5                        # pyserial's own port says 1: readable
    assert port.read(2) == b"18" and port.read(3) == b"18\r"


def test_a_read_waits_for_what_it_asks_until_the_timeout(link):
    port, peer = link
    peer.sendall(b"ab")
    assert port.read(5) == b"ab"                       # what came within 0.2 s
    assert port.read(1) == b"" and port.in_waiting == 0
    peer.sendall(b"cd")
    port.reset_input_buffer()
    assert port.read(1) == b""


def test_a_closed_peer_is_a_serial_error(link):
    port, peer = link
    peer.close()
    with pytest.raises(serial.SerialException, match="disconnected"):
        port.read(1)


def test_what_arrived_is_waiting_before_any_read(link):
    port, peer = link
    assert port.in_waiting == 0
    peer.sendall(b"z\rt1818\r")
    assert wait_until(lambda: port.in_waiting == 8, 2.0)
    assert port.read(8) == b"z\rt1818\r"


def test_a_write_larger_than_the_socket_takes_at_once_goes_whole(link):
    port, peer = link
    data = bytes(range(256)) * 8192                       # 2 MB: more than the kernel buffers
    got = bytearray()

    def drain() -> None:
        while len(got) < len(data):
            got.extend(peer.recv(65536))
    reader = threading.Thread(target=drain)
    reader.start()
    assert port.write(data) == len(data)
    reader.join(timeout=10)
    assert bytes(got) == data
