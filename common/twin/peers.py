"""Who may open a device twin's port: on this machine, only processes of the twin's own user.

A twin listens on a TCP port (`[sim] host`, 127.0.0.1 by default). On a shared machine
every local user can reach a loopback port, and a process on a twin's line speaks as the
device or as its host: false fixes to the GNSS service, frames to the drive, around the
car's access control. So a connection from this machine is served only if its other end
belongs to the user the twin runs as (Linux: that socket's uid in /proc/net/tcp or tcp6;
elsewhere this cannot be told, and every local process is served). A connection from
another machine, possible only if `host` is not a loopback address, is served: whoever
set it so chose to serve other machines. Sim only: a real device sits on a serial port or
a CAN bus, behind the operating system's permissions.
"""
from __future__ import annotations

import ipaddress
import os
import socket
import struct

TABLES = {socket.AF_INET: "/proc/net/tcp", socket.AF_INET6: "/proc/net/tcp6"}


def refusal(conn: socket.socket) -> str | None:
    """Why the accepted connection `conn` must be closed unserved, or None to serve it."""
    uid = peer_uid(conn)
    if uid is None or uid == os.getuid():        # None: another machine's (or not Linux)
        return None
    return f"a process of uid {uid}, not {os.getuid()} (the twin's own user)"


def peer_uid(conn: socket.socket) -> int | None:
    """The uid owning the other end of a TCP connection, if that end is on this machine;
    None if it is not, or the kernel does not say (not Linux, or it is gone already)."""
    try:
        family, peer, ours = conn.family, _address(conn.getpeername()), _address(conn.getsockname())
        if family == socket.AF_INET6 and ipaddress.IPv6Address(peer[0]).ipv4_mapped:   # IPv4 on "::"
            family, peer, ours = socket.AF_INET, _ipv4(peer), _ipv4(ours)
        table = TABLES.get(family)
        if table is None:
            return None
        # the other end's row: its local address is our peer's, its remote address ours
        want = (_proc_address(family, *peer), _proc_address(family, *ours))
        with open(table) as rows:
            next(rows, None)                     # the header
            for row in rows:
                fields = row.split()
                if (fields[1], fields[2]) == want:
                    return int(fields[7])
    except (OSError, ValueError):
        return None
    return None


def _address(address: tuple) -> tuple[str, int]:
    """(host, port), without an IPv6 scope (`%eth0`)."""
    return address[0].split("%")[0], address[1]


def _ipv4(address: tuple[str, int]) -> tuple[str, int]:
    """An IPv4-mapped IPv6 address as the IPv4 one it maps."""
    return str(ipaddress.IPv6Address(address[0]).ipv4_mapped), address[1]


def _proc_address(family: int, host: str, port: int) -> str:
    """An address as /proc/net/tcp writes it: the address's 32-bit words in the host's
    byte order, each as 8 hex digits, then ':' and the port as 4."""
    packed = socket.inet_pton(family, host)
    words = struct.unpack(f"={len(packed) // 4}I", packed)
    return "".join(f"{w:08X}" for w in words) + f":{port:04X}"

