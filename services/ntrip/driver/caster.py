"""One connection to an NTRIP caster: TCP (or TLS), the request, the answer, the stream.

`CasterLink.open()` connects, asks for the mountpoint and reads the answer; anything but
the mountpoint's stream is a `LinkError` saying why in one line a field engineer acts on
("401 Unauthorized: check the credentials file", "mountpoint X not in the caster's source
table", "caster answered HTML, not NTRIP (text/html)", "connection refused"), with
`kind` (the health counter it bumps) and `refused` (the caster said no: retrying will
not help until a person acts). `read()` then gives the stream's payload bytes, undone from
HTTP chunked transfer encoding (NTRIP 2) when the caster uses it.

`fetch_sourcetable()` asks a caster for its source table (`viena ntrip sources`, doctor).
"""
from __future__ import annotations

import re
import socket
import ssl
from dataclasses import dataclass

from viena.common import clock
from viena.services.ntrip.driver.credentials import Credentials
from viena.services.ntrip.driver.protocol import Answer, NtripProtocol, Position

RECV_BYTES = 65536
#: the longest answer header a caster sends; more is not NTRIP
MAX_HEADER_BYTES = 16384
#: the longest source table read (a national network's lists a few hundred mountpoints)
MAX_TABLE_BYTES = 4 << 20
ICY_OK = b"ICY 200 OK\r\n"


class LinkError(Exception):
    """Why a connection failed or ended: `why` one line, `kind` the health counter,
    `refused` when the caster said no (credentials, mountpoint, not a caster);
    `streamed_s`: how long data came before a stream ended."""

    streamed_s = 0.0

    def __init__(self, why: str, kind: str, refused: bool = False):
        super().__init__(why)
        self.why, self.kind, self.refused = why, kind, refused


@dataclass(frozen=True)
class CasterAddress:
    """Where the caster is and how to talk to it."""

    host: str
    port: int = 2101
    mountpoint: str = ""
    version: str = "2.0"
    tls: bool = False
    ca_file: str = ""               # "": the system's CAs

    @property
    def caster(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def source(self) -> str:
        return f"{self.host}:{self.port}/{self.mountpoint}"


class Dechunker:
    """HTTP/1.1 chunked transfer encoding undone incrementally (NTRIP 2 streams): feed what
    the socket gave, get the payload bytes; ValueError on a malformed stream. (pynmeagps'
    SocketWrapper.dechunk, which pygnssutils uses, loses the next chunk when a read ends
    between a chunk's data and its CRLF.)"""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._left = 0              # bytes of the current chunk still to come
        self._crlf = False          # a chunk's data ended; its CRLF is due
        self.done = False           # the last (empty) chunk came

    def feed(self, data: bytes) -> bytes:
        buf = self._buf
        buf += data
        out = bytearray()
        while not self.done:
            if self._left:
                take = min(self._left, len(buf))
                out += buf[:take]
                del buf[:take]
                self._left -= take
                if self._left:
                    break
                self._crlf = True
            if self._crlf:
                if len(buf) < 2:
                    break
                if buf[:2] != b"\r\n":
                    raise ValueError("a chunk does not end with CRLF")
                del buf[:2]
                self._crlf = False
            end = buf.find(b"\r\n")
            if end < 0:
                if len(buf) > 80:
                    raise ValueError("no chunk size line")
                break
            size_text = bytes(buf[:end]).split(b";")[0].strip()
            try:
                size = int(size_text, 16)
            except ValueError:
                raise ValueError(f"bad chunk size {size_text[:20]!r}") from None
            del buf[:end + 2]
            if size == 0:
                self.done = True
                buf.clear()
            self._left = size
        return bytes(out)


def _connect(address: CasterAddress, timeout_s: float) -> socket.socket:
    """A TCP (or TLS) connection to the caster, or LinkError."""
    try:
        sock = socket.create_connection((address.host, address.port), timeout=timeout_s)
    except ConnectionRefusedError:
        raise LinkError("connection refused", "connection_refused") from None
    except socket.gaierror as exc:
        raise LinkError(f"cannot resolve {address.host} ({exc.strerror})", "unreachable") from None
    except TimeoutError:
        raise LinkError(f"no answer from {address.caster} in {timeout_s:g} s", "unreachable") from None
    except OSError as exc:
        raise LinkError(f"cannot connect: {exc.strerror or exc}", "unreachable") from None
    if not address.tls:
        return sock
    try:
        context = ssl.create_default_context(cafile=address.ca_file or None)
        return context.wrap_socket(sock, server_hostname=address.host)
    except ssl.SSLCertVerificationError as exc:
        sock.close()
        raise LinkError(f"TLS: the caster's certificate is not trusted ({exc.verify_message}): "
                        f"check ca_file", "tls_errors", refused=True) from None
    except (ssl.SSLError, OSError) as exc:
        sock.close()
        raise LinkError(f"TLS: {getattr(exc, 'reason', None) or exc}", "tls_errors") from None
    except Exception:
        sock.close()
        raise


def _split_header(buf: bytes) -> tuple[bytes, bytes] | None:
    """(header, body start) once the answer's header is whole, else None. An NTRIP 1 caster
    answers with the bare line ``ICY 200 OK`` and may send nothing more until it has the
    client's GGA (a VRS): the header ends with that line (what may follow it, a blank line
    or a few headers, `_icy_rest` takes off the stream)."""
    if buf.startswith(ICY_OK):
        return ICY_OK[:-2], buf[len(ICY_OK):]
    end = buf.find(b"\r\n\r\n")
    if end < 0:
        return None
    return buf[:end], buf[end + 4:]


_HEADER_LINE = re.compile(rb"[A-Za-z][A-Za-z0-9-]*: ")


def _icy_rest(data: bytes) -> bytes:
    """The stream after ``ICY 200 OK``, without the blank line or headers some casters send."""
    if data.startswith(b"\r\n"):
        return data[2:]
    if _HEADER_LINE.match(data):
        end = data.find(b"\r\n\r\n", 0, MAX_HEADER_BYTES)
        if end >= 0:
            return data[end + 4:]
    return data


class CasterLink:
    """One connection: `open()`, then `read()` until it raises, then `close()`."""

    def __init__(self, address: CasterAddress, credentials: Credentials | None,
                 protocol: NtripProtocol | None = None, *, position: Position | None = None,
                 timeout_s: float = 10.0):
        self.address, self.credentials = address, credentials
        self.protocol = protocol or NtripProtocol()
        self.position = position            # for the request's GGA, if any
        self.timeout_s = timeout_s
        self.answer: Answer | None = None
        self.bytes_in = 0
        self._sock: socket.socket | None = None
        self._pending = b""                 # body bytes that came with the header
        self._dechunker: Dechunker | None = None
        self._after_icy = False             # the stream's first bytes may end an ICY header

    # -- the connection ----------------------------------------------------------------------
    def open(self) -> Answer:
        """Connect and ask for the mountpoint: the answer if it is the stream, else LinkError."""
        a = self.address
        self._sock = _connect(a, self.timeout_s)
        request = self.protocol.request(a.host, a.port, a.mountpoint, a.version, self.credentials,
                                        self.position)
        try:
            self._sock.sendall(request)
        except OSError as exc:
            raise LinkError(f"caster closed the connection at the request ({exc.strerror or exc})",
                            "dropped") from None
        answer, body = self._read_answer()
        self.answer = answer
        if answer.is_stream:
            if answer.chunked:
                self._dechunker = Dechunker()
            self._after_icy = answer.protocol.upper() == "ICY"
            self._pending = body
            return answer
        raise self._refusal(answer, body)

    def _read_answer(self) -> tuple[Answer, bytes]:
        buf = b""
        deadline = clock.monotonic() + self.timeout_s
        while (split := _split_header(buf)) is None:
            if len(buf) > MAX_HEADER_BYTES:
                raise LinkError("caster answered something that is not NTRIP (no header end)",
                                "not_ntrip", refused=True)
            data = self._recv_until(deadline, "answer")
            if not data:
                raise LinkError("caster closed the connection without answering", "dropped")
            buf += data
        header, body = split
        try:
            return self.protocol.answer(header), body
        except ValueError:
            shown = header.split(b"\r\n", 1)[0][:40].decode("ascii", "replace")
            raise LinkError(f"caster answered something that is not NTRIP ({shown!r})",
                            "not_ntrip", refused=True) from None

    def _recv_until(self, deadline: float, what: str) -> bytes:
        left = deadline - clock.monotonic()
        if left <= 0:
            raise LinkError(f"no {what} from {self.address.caster} in {self.timeout_s:g} s", "unreachable")
        assert self._sock is not None
        try:
            self._sock.settimeout(left)
            return self._sock.recv(RECV_BYTES)
        except TimeoutError:
            raise LinkError(f"no {what} from {self.address.caster} in {self.timeout_s:g} s",
                            "unreachable") from None
        except OSError as exc:
            raise LinkError(f"connection lost while waiting for the {what} ({exc.strerror or exc})",
                            "dropped") from None

    def _refusal(self, answer: Answer, body: bytes) -> LinkError:
        """Why an answer is not the stream, as one line."""
        a = self.address
        if answer.code == 401:
            return LinkError("401 Unauthorized: check the credentials file", "unauthorized", refused=True)
        if answer.code == 403:
            return LinkError("403 Forbidden: this login may not use the mountpoint", "unauthorized",
                             refused=True)
        if answer.code == 404 or (answer.code == 200 and answer.is_sourcetable):
            listed = self._listed_mountpoints(answer, body) if answer.is_sourcetable else []
            have = f" (it lists {', '.join(listed[:4])}{', ...' if len(listed) > 4 else ''})" if listed else ""
            return LinkError(f"mountpoint {a.mountpoint} not in the caster's source table{have}",
                             "mountpoint_unknown", refused=True)
        if answer.code == 200:
            return LinkError(f"caster answered {'HTML' if 'html' in answer.content_type else 'text'}, "
                             f"not NTRIP ({answer.content_type})", "html_answers", refused=True)
        return LinkError(f"caster answered {answer.code} {answer.description}", "http_errors",
                         refused=400 <= answer.code < 500)

    def _listed_mountpoints(self, answer: Answer, body: bytes) -> list[str]:
        """The mountpoints of the source table a v1 caster sends for an unknown one."""
        try:
            text = self._read_table(answer, body)
        except LinkError:
            return []
        return [entry[0] for entry in self.protocol.sourcetable(text) if entry]

    def _read_table(self, answer: Answer, body: bytes) -> str:
        """The rest of a source table answer (until ENDSOURCETABLE or the caster closes)."""
        decoder = Dechunker() if answer.chunked else None
        data = decoder.feed(body) if decoder else body
        deadline = clock.monotonic() + self.timeout_s
        while b"ENDSOURCETABLE" not in data[-64:] and not (decoder and decoder.done):
            if len(data) > MAX_TABLE_BYTES:
                break
            more = self._recv_until(deadline, "source table")
            if not more:
                break
            data += decoder.feed(more) if decoder else more
        return data.decode("utf-8", errors="replace")

    # -- the stream ------------------------------------------------------------------------------
    def read(self, timeout_s: float) -> bytes | None:
        """The stream's next payload bytes; None if none came within `timeout_s`; LinkError
        when the caster ends the stream."""
        if self._pending:
            data, self._pending = self._pending, b""
        else:
            assert self._sock is not None
            try:
                self._sock.settimeout(timeout_s)
                data = self._sock.recv(RECV_BYTES)
            except TimeoutError:
                return None
            except OSError as exc:
                raise LinkError(f"connection lost ({exc.strerror or exc})", "dropped") from None
            if not data:
                raise LinkError("caster closed the stream", "dropped")
        self.bytes_in += len(data)
        if self._after_icy and data:
            self._after_icy = False
            data = _icy_rest(data)
        if self._dechunker is None:
            return data
        try:
            payload = self._dechunker.feed(data)
        except ValueError as exc:
            raise LinkError(f"caster's chunked stream is broken ({exc})", "not_ntrip") from None
        if self._dechunker.done:
            raise LinkError("caster ended the stream", "dropped")
        return payload

    def send(self, data: bytes) -> None:
        """Bytes upstream (a GGA)."""
        assert self._sock is not None
        try:
            self._sock.sendall(data)
        except OSError as exc:
            raise LinkError(f"connection lost while sending ({exc.strerror or exc})", "dropped") from None

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        sock.close()


def fetch_sourcetable(address: CasterAddress, credentials: Credentials | None = None,
                      timeout_s: float = 10.0, protocol: NtripProtocol | None = None) -> list[list[str]]:
    """The caster's source table (STR records); LinkError when it does not give one."""
    protocol = protocol or NtripProtocol()
    link = CasterLink(CasterAddress(address.host, address.port, "", address.version, address.tls,
                                    address.ca_file), credentials, protocol, timeout_s=timeout_s)
    try:
        link._sock = _connect(link.address, timeout_s)
        a = link.address
        link._sock.sendall(protocol.request(a.host, a.port, "", a.version, credentials))
        answer, body = link._read_answer()
        if answer.code == 401:
            raise LinkError("401 Unauthorized: the caster wants a login for its source table (--credentials)",
                            "unauthorized", refused=True)
        if answer.code != 200 or not answer.is_sourcetable:
            why = link._refusal(answer, b"").why if answer.code != 200 or not answer.is_stream else \
                "caster sent a stream, not its source table"
            raise LinkError(why, "not_ntrip", refused=True)
        return protocol.sourcetable(link._read_table(answer, body))
    except OSError as exc:
        raise LinkError(f"connection lost ({exc.strerror or exc})", "dropped") from None
    finally:
        link.close()
