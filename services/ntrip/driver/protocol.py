"""The NTRIP request and answer, from pygnssutils' GNSSNTRIPClient used as a library.

What is reused: the request it builds (`_set_headers`: the GET line, Host, the NTRIP
User-Agent, Basic authorisation, ``Ntrip-Version: Ntrip/2.0`` and the ``Ntrip-GGA``
header for v2, or the GGA after the request for v1), its parsing of the answer's status
line and headers (`_parse_response_header`, and `is_gnssdata`, `is_sourcetable`,
`content_type`, `encoding` from them: ICY, HTTP/1.x, SOURCETABLE), its source-table
parsing (`_parse_sourcetable`) and its GGA sentence (`_format_gga`, pynmeagps), which
asks its "app" (this class) for the position.

What is not: its `run()` and read thread. Their retry policy is not one a caster accepts
(5 s doubling, given up after 5 tries, never reset, and a normal end of stream retried
after 5 s); the thread logs the request headers, Basic credentials included, at DEBUG;
it reads its inactivity timeout from the wall clock; and its reader loses the bytes that
came with the answer's header, and spins on a closed socket. So the client calls the
pieces above and owns the socket, the loop (driver/client.py) and the framing
(driver/rtcm3.py). These are private methods of pygnssutils 1.3: the tests in
tests/ntrip/test_ntrip_client.py pin what is used of them.
"""
from __future__ import annotations

import logging
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import NamedTuple

from pygnssutils.globals import ENCODE_CHUNKED, NOGGA
from pygnssutils.gnssntripclient import GNSSNTRIPClient

from viena.services.ntrip.driver.credentials import Credentials

#: what the answer's content type says when a web server, not a caster, answers
TEXT_TYPES = ("text/",)
#: pygnssutils' fix names (its FIXES table) for our solution kinds (it has none for DGPS)
_GGA_FIX = {"none": "NO FIX", "single": "3D", "sbas": "3D", "dgps": "3D", "float": "RTK FLOAT",
            "fixed": "RTK FIXED"}


class Position(NamedTuple):
    """Where the car is, for the GGA a VRS or nearest-base caster chooses its base by."""

    lat_deg: float
    lon_deg: float
    height_m: float                 # ellipsoidal (sent as the GGA altitude, geoid separation 0)
    kind: str = "single"            # one of the fix schema's SOLUTION_KINDS
    sats: int = 8
    hdop: float = 1.0
    diff_age_s: float = 0.0
    base_id: str = "0"


@dataclass
class Answer:
    """The caster's answer to the request, as pygnssutils parsed it."""

    protocol: str                   # ICY, HTTP/1.1, HTTP/1.0, SOURCETABLE
    code: int
    description: str
    headers: dict = field(default_factory=dict)
    content_type: str = ""
    chunked: bool = False
    is_stream: bool = False         # ICY 200, or 200 gnss/data (or any 200 that is neither text nor a table)
    is_sourcetable: bool = False


@contextmanager
def _loggers_kept(*names: str):
    """GNSSNTRIPClient's constructor gives the pyrtcm and pyspartn loggers a stream
    handler of its own and level DEBUG, each time: put them back as they were."""
    saved = {n: (logging.getLogger(n).level, list(logging.getLogger(n).handlers)) for n in names}
    try:
        yield
    finally:
        for name, (level, handlers) in saved.items():
            logger = logging.getLogger(name)
            logger.setLevel(level)
            logger.handlers[:] = handlers


class NtripProtocol:
    """The request and answer pieces of one GNSSNTRIPClient, which is never run."""

    def __init__(self) -> None:
        with _loggers_kept("pyrtcm", "pyspartn"):
            self._client = GNSSNTRIPClient(app=self)
        self._position: Position | None = None

    # -- GNSSNTRIPClient's "app" --------------------------------------------------------------
    def get_coordinates(self) -> dict:
        """The position `_format_gga` puts in the GGA (the app interface it calls)."""
        p = self._position
        if p is None:
            raise ValueError("no position")
        return {"lat": p.lat_deg, "lon": p.lon_deg, "alt": p.height_m, "sep": 0.0,
                "fix": _GGA_FIX.get(p.kind, "3D"), "sip": p.sats, "hdop": p.hdop,
                "diffage": round(p.diff_age_s, 1) if p.diff_age_s else "",
                "diffstation": p.base_id if p.diff_age_s else ""}

    # -- the pieces ---------------------------------------------------------------------------
    def gga(self, position: Position) -> bytes:
        """A GGA sentence (with CRLF) for `position`."""
        self._position = position
        self._client.settings = {"ggamode": 0}
        try:
            raw, _ = self._client._format_gga()
        finally:
            self._position = None
        if raw is None:
            raise ValueError("pygnssutils made no GGA of this position")
        return raw

    def request(self, host: str, port: int, mountpoint: str, version: str,
                credentials: Credentials | None, position: Position | None = None) -> bytes:
        """The request for `mountpoint` ("" asks for the source table); with a position,
        the GGA goes in the Ntrip-GGA header (v2) or after the request (v1)."""
        self._position = position
        self._client.settings = {
            "server": host, "port": port, "mountpoint": mountpoint, "version": version,
            "ntripuser": credentials.user if credentials else "",
            "ntrippassword": credentials.password if credentials else "",
            "ggainterval": NOGGA if position is None else 1, "ggamode": 0}
        try:
            text = self._client._set_headers(self._client.settings)
        finally:
            self._position = None
            self._client.settings = {"ntripuser": "", "ntrippassword": ""}   # no copy kept
        if credentials is None:     # pygnssutils always authorises; an open caster needs none
            text = "".join(line for line in text.splitlines(keepends=True)
                           if not line.startswith("Authorization:"))
        return text.encode()

    def answer(self, header: bytes) -> Answer:
        """The status line and headers (`header` without the blank line); ValueError when
        it is not HTTP, ICY or SOURCETABLE."""
        c = self._client
        c._response_headers = {}            # pygnssutils keeps the last answer's otherwise
        try:
            c._parse_response_header(header + b"\r\n\r\n")
            status = c.status
            code = int(status["code"])
        except (IndexError, ValueError, KeyError):
            raise ValueError("not an HTTP, ICY or SOURCETABLE answer") from None
        ctype = c.content_type.split(";")[0].strip().lower()
        sourcetable = c.is_sourcetable
        stream = code == 200 and not sourcetable and (
            c.is_gnssdata or not ctype.startswith(TEXT_TYPES))
        return Answer(protocol=status["protocol"], code=code, description=str(status["description"]),
                      headers=dict(c._response_headers), content_type=ctype,
                      chunked=bool(c.encoding & ENCODE_CHUNKED), is_stream=stream,
                      is_sourcetable=sourcetable)

    def sourcetable(self, text: str) -> list[list[str]]:
        """The STR records of a source table, each as its fields after "STR"."""
        return self._client._parse_sourcetable(text)
