"""zenoh's own log in the router's log: who was denied what, who was cut by a limit, which
TLS connections failed before any session; one line per cause every 10 s at most, with
how many came meanwhile, so a flood is a line every 10 s, not a line per message.

zenoh decides access control, downsampling and TLS in Rust and says so only in its own
log (the `tracing` crate; a denial is a TRACE event). zenoh-python 1.10 writes that log
to standard output, with no bridge to Python's logging and no callback or counter for a
denial (its `stats` feature is not built in). So `viena router` asks zenoh for exactly
those targets (DIRECTIVES; RUST_LOG, if set, wins), reads its standard output through a
pipe, and turns what matters into lines of its own log, naming the client by its
certificate's common name (from the denial itself, or the router's links), else by zenoh
id. Everything else zenoh writes goes to the log as it is (logger "zenoh").

zenoh logs every access-control decision at TRACE, allowed ones too (one line per
message and subscriber), and every message a limit cuts: the reader drops those on sight
(a byte comparison), reads every 50 ms rather than every line, and still the router pays
zenoh's formatting: about 2 % of an x86 core per 1,500 lines a second
(docs/placement.md#limits-before-and-after-authentication).
"""
from __future__ import annotations

import fcntl
import logging
import os
import re
import threading
import time
from typing import Any

from viena.common.log import Throttled

log = logging.getLogger("viena.router")
zenoh_log = logging.getLogger("zenoh")

DIRECTIVES = ",".join([
    "error",
    "zenoh::net::routing::interceptor::access_control=trace",   # denials (TRACE), unknown subjects (INFO)
    "zenoh::net::routing::interceptor::downsampling=trace",     # a message cut by a limit (TRACE)
    "zenoh_link_tls=warn",                                      # a failed TLS handshake (WARN)
])
INTERVAL_S = 10.0
PIPE_BYTES = 1 << 20                  # zenoh blocks when the pipe is full: room for bursts
READ_PERIOD_S = 0.05                  # 1 MB every 50 ms is 100,000 lines a second
_F_SETPIPE_SZ = 1031                  # Linux fcntl

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_LINE = re.compile(r"^\S+\s+(?P<level>TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:.*?ThreadId\((?P<thread>\d+)\)\s+)?"
                   r"(?P<target>[\w:]+): (?P<message>.*)$")
_DENIED_CACHED = re.compile(r"^Using cached result: (?P<zid>[0-9a-f]+) is unauthorized to (?P<action>.+) "
                            r"on (?P<key>\S+)$")
_DECIDED = re.compile(r"^(?P<zid>[0-9a-f]+) on (?P<subject>\S+) is (?P<verdict>authorized|unauthorized) to "
                      r"(?P<action>.+) on (?P<key>\S+)$")
_CACHING = re.compile(r"^ACL \((?:ingress|egress)\): caching permissions for `(?P<key>[^`]*)`")
#: the last of the decisions zenoh makes (and logs) for a key it starts caching
_LAST_CACHED = "Declare Liveliness Subscriber"
_NO_SUBJECT = re.compile(r"^(?P<zid>[0-9a-f]+) did not match any configured ACL subject")
_CUT = re.compile(r"^Message dropped by the downsampling interceptor: (?P<message>\w+).*?\((?P<key>[^()]*)\) "
                  r"(?:from|to):(?P<face>.*)$")
_MESSAGES = {"Push": "puts", "Request": "queries", "Response": "replies"}
_CUT_BYTES = b"dropped by the downsampling interceptor: "
_LAST_CACHED_BYTES = _LAST_CACHED.encode()
_COMMON_NAME = re.compile(r"CertCommonName\(([^)]*)\)")
_ZID = re.compile(r"\b([0-9a-f]{8,32})\b")        # a face shows the first 8 digits
_LEVELS = {"TRACE": 5, "DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARN": logging.WARNING,
           "ERROR": logging.ERROR}
_HINT = ". Hint: increase the system open file limit."      # zenoh's, on every TLS accept error


class ZenohLog:
    """Reads zenoh's log, line by line (`feed`), and writes what matters through Throttled. The
    router's session, once open (`session`), names clients zenoh names only by id."""

    def __init__(self, interval_s: float = INTERVAL_S, clock=None):
        self.session: Any = None                     # a zenoh.Session
        self.denied = Throttled(log, "denied", interval_s, clock=clock)
        self.cut = Throttled(log, "cut by the router's limit", interval_s, clock=clock)
        self.refused = Throttled(log, "TLS connection failed before any session", interval_s, clock=clock)
        self.names: dict[str, str] = {}              # zenoh id -> certificate's common name
        self._caching: dict[str | None, str] = {}    # thread -> key zenoh caches decisions for
        self._cuts: dict[bytes, str] = {}            # what zenoh says it cut -> the cause we log

    # -- reading ---------------------------------------------------------------------------
    @classmethod
    def capture(cls) -> ZenohLog:
        """Send zenoh's log (standard output of this process) to a new ZenohLog, read by a
        thread of its own. Call before anything starts zenoh's log (it can start once)."""
        import zenoh

        reader = cls()
        read_end, write_end = os.pipe()
        try:
            fcntl.fcntl(write_end, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass                                     # the default 64 KB: still read at once
        os.dup2(write_end, 1)
        os.close(write_end)
        zenoh.init_log_from_env_or(DIRECTIVES)
        threading.Thread(target=reader._read, args=(read_end,), name="zenoh-log", daemon=True).start()
        return reader

    def _read(self, fd: int) -> None:
        rest = b""
        while chunk := os.read(fd, PIPE_BYTES):
            time.sleep(READ_PERIOD_S)                # let lines gather: one read, not one per line
            lines = (rest + chunk).split(b"\n")
            rest = lines.pop()
            for line in lines:
                try:
                    self.feed(line)
                except Exception:                    # never stop reading: zenoh would block
                    log.exception("cannot read zenoh's log line %r", line[:200])

    # -- one line --------------------------------------------------------------------------
    def feed(self, line: bytes) -> None:
        # nearly all lines: a message allowed (but the last decision of a key's caching,
        # which ends it: see _access_control), or, under a flood, one cut: both cheap
        if b" is authorized to " in line and _LAST_CACHED_BYTES not in line:
            return
        if _CUT_BYTES in line:
            self._cut(line)
        else:
            self._line(line.decode(errors="replace"))

    def _cut(self, line: bytes) -> None:
        """A message cut by a limit, read as bytes: a flood is thousands a second."""
        what = line.partition(_CUT_BYTES)[2].rstrip()
        cause = self._cuts.get(what)
        if cause is None:
            cut = _CUT.match("Message dropped by the downsampling interceptor: " + what.decode(errors="replace"))
            if cut is None:
                return
            cause = f"{_MESSAGES.get(cut['message'], cut['message'])} on {cut['key']} from {self.name(cut['face'])}"
            if len(self._cuts) > 1000:
                self._cuts.clear()
            self._cuts[what] = cause
        self.cut.log(cause)

    def _line(self, text: str) -> None:
        m = _LINE.match(_ANSI.sub("", text).rstrip())
        if m is None:
            if text.strip():
                zenoh_log.info("%s", _ANSI.sub("", text).rstrip())
            return
        level, thread, target, message = m["level"], m["thread"], m["target"], m["message"]
        if target.endswith("::access_control"):
            self._access_control(thread, message, level)
        elif target.endswith("::downsampling"):         # its rules, and "some were dropped" once
            zenoh_log.debug("%s: %s", target, message)
        elif target.startswith("zenoh_link_tls") and level == "WARN":
            self.refused.log("TLS handshakes failed", message.removesuffix(_HINT))
        else:
            zenoh_log.log(_LEVELS[level], "%s: %s", target, message)

    def _access_control(self, thread: str | None, message: str, level: str) -> None:
        if caching := _CACHING.match(message):
            # zenoh decides every kind of message for a key when it first sees the key, and
            # logs each decision (the last: _LAST_CACHED): no message was denied there
            self._caching[thread] = caching["key"]
            return
        if decided := _DECIDED.match(message):
            if common_name := _COMMON_NAME.search(decided["subject"]):
                self._remember(decided["zid"], common_name[1])
            precomputed = self._caching.get(thread) == decided["key"]
            if precomputed and decided["action"].startswith(_LAST_CACHED):
                del self._caching[thread]
            if precomputed or decided["verdict"] == "authorized":
                return
            denied = decided
        elif cached := _DENIED_CACHED.match(message):
            denied = cached
        elif unknown := _NO_SUBJECT.match(message):
            log.warning("%s is in no access-control subject: everything it sends is denied",
                        self.name(unknown["zid"]))
            return
        else:
            if level != "TRACE":
                zenoh_log.log(_LEVELS[level], "access control: %s", message)
            return
        self.denied.log(f"{denied['action']} from {self.name(denied['zid'])}", denied["key"])

    # -- who -------------------------------------------------------------------------------
    def _remember(self, zid: str, common_name: str) -> None:
        if len(self.names) > 10_000:                 # sessions come and go: forget old ones
            self.names.clear()
        self.names[zid] = common_name

    def name(self, text: str) -> str:
        """`common-name (zid)` for the zenoh id in `text` (whole, or the first digits a
        face shows), from the router's links when no denial named it yet; the id alone for
        a client without a certificate."""
        found = _ZID.search(text)
        if found is None:
            return text.strip()
        zid = self._known(found[1])
        if zid is None and self.session is not None:
            try:
                for link in self.session.info.links():
                    if link.auth_identifier:
                        self._remember(str(link.zid), link.auth_identifier)
            except Exception:                        # the session is closing
                pass
            zid = self._known(found[1])
            if zid is None:                          # asked once: no certificate, or gone
                self._remember(found[1], "")
        zid = zid or found[1]
        common_name = self.names.get(zid)
        return f"{common_name} (zid {zid})" if common_name else f"zid {zid}"

    def _known(self, zid: str) -> str | None:
        if zid in self.names:
            return zid
        if len(zid) < 32:
            return next((z for z in self.names if z.startswith(zid)), None)
        return None
