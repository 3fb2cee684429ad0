"""How the caster twin answers one connection, the HTTP side of NTRIP: the TLS handshake,
the request read within its deadline, then what protocol.py words for it (the source table,
400, 401, 404, the HTML page of the `answer_html` fault) or the RTCM stream (stream.py)."""
from __future__ import annotations

import logging
import secrets
import socket
import ssl
from collections.abc import Mapping
from typing import TYPE_CHECKING

from viena.common import clock

from . import protocol
from .clients import SEND_TIMEOUT_S, TICK_S, Client, Closed, readable, send
from .stream import RtcmStream

if TYPE_CHECKING:
    from .caster import CasterTwin

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 10.0          # real seconds a connection may take to send its request


def serve(caster: CasterTwin, client: Client) -> None:
    """Serve one connection to its end (a client thread's whole life); why it ended goes
    in `client.why_closed`, and the socket is closed whatever happened."""
    conn = client._sock
    why = "closed"
    try:
        conn.settimeout(SEND_TIMEOUT_S)
        if caster.tls_context is not None:
            conn = client._sock = _tls_handshake(caster.tls_context, client, conn)
        request = _read_request(client, conn)
        client.request = request
        _answer(caster, client, conn, request)
        why = client.why_closed or "answered"
    except Closed as closed:
        why = str(closed)
    except (OSError, ssl.SSLError) as exc:
        why = f"connection error: {exc}"
    finally:
        why = client._kill or why
        try:
            conn.close()
        except OSError:
            pass
        client.why_closed = why
        client.closed_s = clock.monotonic()
        log.info("client %d (%s:%d) %s: %s", client.id, *client.peer[:2], client.answer or "no answer", why)


def _tls_handshake(context: ssl.SSLContext, client: Client, conn: socket.socket) -> ssl.SSLSocket:
    try:
        return context.wrap_socket(conn, server_side=True)
    except (ssl.SSLError, OSError) as exc:
        client.answer = "tls"
        raise Closed(f"TLS handshake failed: {exc}") from None


def _read_request(client: Client, conn) -> protocol.Request:
    data = b""
    deadline = clock.monotonic() + REQUEST_TIMEOUT_S
    while True:
        if client._kill:
            raise Closed(client._kill)
        left = deadline - clock.monotonic()
        if left <= 0:
            client.answer = "timeout"
            raise Closed(f"no request within {REQUEST_TIMEOUT_S:g} s")
        if not readable(conn, min(left, TICK_S)):
            continue
        more = conn.recv(4096)
        if not more:
            raise Closed("closed before its request")
        data += more
        try:
            request = protocol.parse_request(data)
        except protocol.BadRequest as exc:
            client.answer = "400"
            send(client, conn, protocol.bad_request())
            raise Closed(f"bad request: {exc}") from None
        if request is not None:
            return request


def _answer(caster: CasterTwin, client: Client, conn, request: protocol.Request) -> None:
    v2 = (request.ntrip2 and "2.0" in caster.versions) or "1.0" not in caster.versions
    client.version = "2.0" if v2 else "1.0"
    client.mountpoint = request.mountpoint
    if caster.answer_html:
        client.answer = "html"
        send(client, conn, protocol.html_page())
        return
    if request.method != "GET":
        client.answer = "400"
        send(client, conn, protocol.bad_request(v2))
        return
    mount = caster.mountpoints.get(request.mountpoint)
    if mount is None:
        if request.mountpoint and v2:
            client.answer = "404"
            send(client, conn, protocol.not_found(request.mountpoint))
        else:
            client.answer = "sourcetable"
            send(client, conn, protocol.sourcetable(caster.sourcetable(), v2))
        return
    credentials = request.credentials()
    client.user = credentials[0] if credentials else None
    if caster.users and not _authorized(caster.users, credentials):
        client.answer = "401"
        send(client, conn, protocol.unauthorized(request.mountpoint, v2))
        return
    client.answer = "stream"
    send(client, conn, protocol.stream_ok(v2, caster.icy_headers))
    RtcmStream(caster, client, conn, mount, v2).run()


def _authorized(users: Mapping[str, str], credentials: tuple[str, str] | None) -> bool:
    if credentials is None or credentials[0] not in users:
        return False
    return secrets.compare_digest(credentials[1].encode(), users[credentials[0]].encode())
