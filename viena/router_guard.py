"""What an outsider without a certificate can cost the router's TLS listeners (issue 24).

zenoh's TLS listener (1.10) accepts a TCP connection, then gives it a place among 64
concurrent handshakes for `tls_handshake_timeout_ms` (10 s unless the endpoint says
otherwise); and after every failed handshake (a timeout, garbage, a connection closed
early) its accept loop sleeps 100 ms, during which nobody's handshake moves
(eclipse-zenoh/zenoh#2685). 150 silent connections, re-opened as they are dropped, kept
every certificate holder out. Two bounds that need no change to zenoh:

- a short handshake timeout on every tls/ listener that sets none (2 s): a real handshake
  is one round trip on the router's side, and a slot held by a stalled peer comes free
  as fast as zenoh's 100 ms pause lets anything come free;
- Linux's TCP_DEFER_ACCEPT on the listening sockets: the kernel hands zenoh a connection
  only once its first bytes (a TLS client speaks first) arrive, so a silent connection
  waits in the kernel, costs zenoh nothing, and is accepted (then timed out) only after
  `defer_s`.

Neither stops an outsider who makes handshakes fail ten times a second (connect, send
anything, close): only a limit per source address before zenoh (nftables on the Pi,
docs/placement.md#limits-before-and-after-authentication) or a fixed zenoh does.
"""
from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger("viena.router")

#: zenoh's endpoint setting (io/zenoh-link-commons/src/tls.rs), in the endpoint's config part
HANDSHAKE_TIMEOUT_KEY = "tls_handshake_timeout_ms"
HANDSHAKE_TIMEOUT_MS = 2000
#: how long a connection that says nothing waits in the kernel before zenoh sees it
DEFER_ACCEPT_S = 600


def with_handshake_timeout(endpoint: str, timeout_ms: int) -> str:
    """`endpoint` with a TLS handshake timeout, unless it is not tls/ or sets one already
    (zenoh's syntax: PROTOCOL/ADDRESS?METADATA#CONFIG, CONFIG as key=value;key=value)."""
    if not endpoint.startswith("tls/") or timeout_ms <= 0:
        return endpoint
    base, hash_, config = endpoint.partition("#")
    if any(item.split("=", 1)[0] == HANDSHAKE_TIMEOUT_KEY for item in config.split(";") if item):
        return endpoint
    setting = f"{HANDSHAKE_TIMEOUT_KEY}={timeout_ms}"
    return f"{base}#{config};{setting}" if config else f"{base}#{setting}"


def listening_tcp_sockets():
    """This process's listening TCP sockets, each a duplicate of the descriptor (close it
    when done; options set on it are the socket's)."""
    try:
        names = os.listdir("/proc/self/fd")
    except OSError:                                 # not Linux
        return
    for name in names:
        try:
            fd = os.dup(int(name))
        except OSError:                             # gone already (listdir's own)
            continue
        try:
            sock = socket.socket(fileno=fd)
        except OSError:                             # not a socket
            os.close(fd)
            continue
        try:
            if (sock.family in (socket.AF_INET, socket.AF_INET6) and sock.type == socket.SOCK_STREAM
                    and sock.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN)):
                yield sock
                continue
        except OSError:
            pass
        sock.close()


def defer_silent_connections(defer_s: int) -> list[str]:
    """TCP_DEFER_ACCEPT on every listening TCP socket of this process (a secured router's
    are all TLS: plain ones are refused next to them); the addresses it was set on."""
    option = getattr(socket, "TCP_DEFER_ACCEPT", None)
    if defer_s <= 0 or option is None:
        return []
    done = []
    for sock in listening_tcp_sockets():
        with sock:
            sock.setsockopt(socket.IPPROTO_TCP, option, defer_s)
            host, port = sock.getsockname()[:2]
            done.append(f"{host}:{port}")
    return done
