"""What an NTRIP caster says, as real ones say it (BKG's NtripCaster, SNIP, RTK2go).

NTRIP 1.0 (a request without `Ntrip-Version: Ntrip/2.0`, HTTP/1.0 style):
- a mountpoint: `ICY 200 OK` then the raw stream;
- `GET /` or an unknown mountpoint: `SOURCETABLE 200 OK`, the table, `ENDSOURCETABLE`,
  closed (a v1 client learns its mountpoint is wrong from being sent the table);
- wrong or missing credentials: `HTTP/1.0 401 Unauthorized` with an HTML body.

NTRIP 2.0 (`Ntrip-Version: Ntrip/2.0`, HTTP/1.1):
- a mountpoint: `HTTP/1.1 200 OK`, `Content-Type: gnss/data`, chunked transfer encoding;
- `GET /`: `Content-Type: gnss/sourcetable`;
- an unknown mountpoint: `404 Not Found`; wrong credentials: `401 Unauthorized` with
  `WWW-Authenticate: Basic realm="/MOUNT"`.

The source table's records (NTRIP 2.0, appendix): CAS (the caster), NET (its network),
STR (one per mountpoint: 19 fields, its position, format, message rates, whether it wants
the rover's GGA).
"""
from __future__ import annotations

import base64
import binascii
from dataclasses import dataclass, field
from email.utils import formatdate

from viena.common import clock

SERVER = "NTRIP VienaCasterTwin/2.0"
MAX_REQUEST_BYTES = 8192


class BadRequest(ValueError):
    """Not an HTTP request a caster answers."""


@dataclass
class Request:
    method: str
    path: str
    http_version: str
    headers: dict[str, str] = field(default_factory=dict)   # names in lower case
    rest: bytes = b""                                        # what came after the headers (v1 GGA)

    @property
    def ntrip2(self) -> bool:
        return "ntrip/2" in self.headers.get("ntrip-version", "").lower()

    @property
    def mountpoint(self) -> str:
        return self.path.split("?", 1)[0].lstrip("/")

    def credentials(self) -> tuple[str, str] | None:
        """(user, password) of a Basic Authorization header, or None."""
        value = self.headers.get("authorization", "")
        scheme, _, token = value.partition(" ")
        if scheme.lower() != "basic":
            return None
        try:
            text = base64.b64decode(token.strip(), validate=True).decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            return None
        user, sep, password = text.partition(":")
        return (user, password) if sep else None


def parse_request(data: bytes) -> Request | None:
    """The request in `data`, or None while its headers are not complete."""
    head, sep, rest = data.partition(b"\r\n\r\n")
    if not sep:
        head, sep, rest = data.partition(b"\n\n")            # a bare-LF client
    if not sep:
        if len(data) > MAX_REQUEST_BYTES:
            raise BadRequest("request headers too long")
        return None
    lines = head.decode("latin-1").replace("\r\n", "\n").split("\n")
    parts = lines[0].split()
    if len(parts) != 3 or not parts[2].upper().startswith(("HTTP/", "RTSP/")):
        raise BadRequest(f"not an HTTP request line: {lines[0][:60]!r}")
    headers = {}
    for line in lines[1:]:
        name, colon, value = line.partition(":")
        if colon:
            headers[name.strip().lower()] = value.strip()
    return Request(parts[0].upper(), parts[1], parts[2].upper(), headers, rest)


# -- responses --------------------------------------------------------------------------------------
def _date() -> str:
    return formatdate(clock.time(), usegmt=True)


def _head(status: str, ntrip2: bool, headers: list[str]) -> bytes:
    lines = [f"HTTP/1.1 {status}" if ntrip2 else f"HTTP/1.0 {status}"]
    if ntrip2:
        lines.append("Ntrip-Version: Ntrip/2.0")
    lines += [f"Server: {SERVER}", f"Date: {_date()}", *headers]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def stream_ok(ntrip2: bool, icy_headers: bool = False) -> bytes:
    """The answer before a stream. v1: a bare `ICY 200 OK` line (NTRIP 1.0's own form) or,
    with `icy_headers`, the line with Server and Date headers as some casters send."""
    if not ntrip2:
        if icy_headers:
            return f"ICY 200 OK\r\nServer: {SERVER}\r\nDate: {_date()}\r\n\r\n".encode("latin-1")
        return b"ICY 200 OK\r\n"
    return _head("200 OK", True, ["Cache-Control: no-store, no-cache, max-age=0", "Pragma: no-cache",
                                  "Connection: close", "Content-Type: gnss/data",
                                  "Transfer-Encoding: chunked"])


def chunk(data: bytes) -> bytes:
    """One HTTP/1.1 chunk (v2 streams)."""
    return f"{len(data):X}\r\n".encode() + data + b"\r\n"


LAST_CHUNK = b"0\r\n\r\n"


def sourcetable(body: str, ntrip2: bool) -> bytes:
    data = body.encode("utf-8")
    if not ntrip2:
        head = (f"SOURCETABLE 200 OK\r\nServer: {SERVER}\r\nDate: {_date()}\r\n"
                f"Content-Type: text/plain\r\nContent-Length: {len(data)}\r\nConnection: close\r\n\r\n")
        return head.encode("latin-1") + data
    return _head("200 OK", True, ["Connection: close", "Content-Type: gnss/sourcetable",
                                  f"Content-Length: {len(data)}"]) + data


def _html(status: str, text: str) -> bytes:
    return (f"<!DOCTYPE html>\r\n<html><head><title>{status}</title></head>"
            f"<body><h1>{status}</h1><p>{text}</p></body></html>\r\n").encode()


def unauthorized(mountpoint: str, ntrip2: bool) -> bytes:
    body = _html("401 Unauthorized", "The server does not recognize your privileges to the requested entity/stream.")
    return _head("401 Unauthorized", ntrip2, [f'WWW-Authenticate: Basic realm="/{mountpoint}"',
                                              "Content-Type: text/html", f"Content-Length: {len(body)}",
                                              "Connection: close"]) + body


def not_found(mountpoint: str) -> bytes:
    body = _html("404 Not Found", f"No mountpoint /{mountpoint} on this caster.")
    return _head("404 Not Found", True, ["Content-Type: text/html", f"Content-Length: {len(body)}",
                                         "Connection: close"]) + body


def bad_request(ntrip2: bool = True) -> bytes:
    body = _html("400 Bad Request", "The request is not one this caster answers.")
    return _head("400 Bad Request", ntrip2, ["Content-Type: text/html", f"Content-Length: {len(body)}",
                                             "Connection: close"]) + body


def html_page() -> bytes:
    """What a web server (a router's login page, a captive portal) answers on the port."""
    body = (b"<!DOCTYPE html>\r\n<html><head><title>Welcome</title></head><body>"
            b"<h1>It works!</h1><p>This is a web server, not an NTRIP caster.</p></body></html>\r\n")
    return (f"HTTP/1.1 200 OK\r\nServer: Apache\r\nDate: {_date()}\r\nContent-Type: text/html; charset=UTF-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode("latin-1") + body


# -- the source table -------------------------------------------------------------------------------
@dataclass(frozen=True)
class StreamEntry:
    """One STR record: a mountpoint as the table describes it."""
    mountpoint: str
    identifier: str
    format: str                     # "RTCM 3.1"
    format_details: str             # "1004(1),1005(10),1033(30)"
    carrier: int                    # 0, 1 (L1), 2 (L1+L2)
    nav_system: str                 # "GPS", "GPS+GLO"
    network: str
    country: str                    # ISO 3166 alpha-3
    lat_deg: float
    lon_deg: float
    nmea: int                       # 1: send GGA (the stream depends on the rover's position)
    solution: int                   # 0 single base, 1 network
    generator: str
    authentication: str             # "N" none, "B" basic
    bitrate: int

    def line(self) -> str:
        fields = ["STR", self.mountpoint, self.identifier, self.format, self.format_details,
                  str(self.carrier), self.nav_system, self.network, self.country,
                  f"{self.lat_deg:.4f}", f"{self.lon_deg:.4f}", str(self.nmea), str(self.solution),
                  self.generator, "none", self.authentication, "N", str(self.bitrate), "none"]
        return ";".join(fields)


def table(host: str, port: int, network: str, country: str, lat_deg: float, lon_deg: float,
          entries: list[StreamEntry], authentication: str) -> str:
    """The whole source table text, ENDSOURCETABLE included."""
    lines = [f"CAS;{host};{port};VienaCasterTwin;IST;0;{country};{lat_deg:.4f};{lon_deg:.4f};0.0.0.0;0;none",
             f"NET;{network};IST;{authentication};N;none;none;none;none"]
    lines += [e.line() for e in entries]
    lines.append("ENDSOURCETABLE")
    return "\r\n".join(lines) + "\r\n"
