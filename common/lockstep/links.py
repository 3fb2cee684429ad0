"""Serial twins reached in memory: ``mem://NAME`` is a `ByteTwin` served in this process.

The car in one process (issue 27) has no sockets between a driver and its twin: the sim
serves each twin as a `MemoryEndpoint` instead of a `SerialEndpoint`, and the unchanged
driver opens ``mem://NAME`` through `open_link` (common/link.py) as it opens
``socket://127.0.0.1:PORT`` or ``/dev/ttyUSB0``.

There is no pump: the reading thread drives the twin. A read asks the twin what it has sent
by now (`poll`); when that is nothing it waits on a clock event until the twin is next due
(`next_due`), a write arrives or the read times out. A write is fed to the twin inline. On
the virtual clock a simulated device therefore costs no thread of its own, and time jumps
straight to the twin's next byte; on the wall clock (tests) the same code reads in real time.

Which endpoints a ``mem://`` URL can reach: those of the calling thread's clock
(`ports_of`). The lockstep runner's threads all live on its virtual clock, so the twins the
sim serves there and the drivers that open them meet without being told of each other, two
simulations in one process never see each other's ports, and the ports go when the clock
does. On the wall clock there is one set per process.
"""
from __future__ import annotations

import logging
import math
import threading
import weakref
from typing import Any

import serial

from viena.common import clock
from viena.common.link import CHUNK, DEFAULT_BAUDRATE, MEMORY_SCHEME, Link
from viena.common.twin.serial_port import ByteTwin

log = logging.getLogger(__name__)

#: the shortest wait of an empty read (ns): a twin due "now" that had nothing yet (its float
#: times rounded), or a read asked to wait a hair's breadth (a remainder of a driver's float
#: arithmetic), waits this long, so that time moves on a virtual clock (which counts whole
#: nanoseconds and would otherwise stand still while the reader spins)
MIN_WAIT_NS = 1_000


class MemoryPorts:
    """The endpoints of one simulation, by name: what ``mem://NAME`` opens."""

    def __init__(self) -> None:
        self._endpoints: dict[str, MemoryEndpoint] = {}
        self._lock = threading.Lock()

    def serve(self, twin: ByteTwin, name: str) -> MemoryEndpoint:
        """Serve `twin` as ``mem://name`` (a ValueError if that name is served already)."""
        return MemoryEndpoint(twin, name, self)

    def endpoint(self, name: str) -> MemoryEndpoint:
        """The endpoint served as `name`; serial.SerialException (as for a missing port) if none."""
        with self._lock:
            found = self._endpoints.get(name)
            names = sorted(self._endpoints)
        if found is None:
            there = ", ".join(f"{MEMORY_SCHEME}://{n}" for n in names) or "none"
            raise serial.SerialException(f"{MEMORY_SCHEME}://{name}: no twin is served under that name "
                                         f"(served here: {there})")
        return found

    def names(self) -> list[str]:
        with self._lock:
            return sorted(self._endpoints)

    def stop(self) -> None:
        """Stop every endpoint (their hosts' next reads fail, as when the sim ends)."""
        with self._lock:
            endpoints = list(self._endpoints.values())
        for endpoint in endpoints:
            endpoint.stop()

    def _add(self, endpoint: MemoryEndpoint) -> None:
        with self._lock:
            if endpoint.name in self._endpoints:
                raise ValueError(f"{endpoint.url} is served already")
            self._endpoints[endpoint.name] = endpoint

    def _remove(self, endpoint: MemoryEndpoint) -> None:
        with self._lock:
            if self._endpoints.get(endpoint.name) is endpoint:
                del self._endpoints[endpoint.name]


#: clock -> its ports; weak, so a simulation's ports go with its clock
_PORTS: weakref.WeakKeyDictionary[Any, MemoryPorts] = weakref.WeakKeyDictionary()
_PORTS_LOCK = threading.Lock()


def ports_of(sim_clock: Any = None) -> MemoryPorts:
    """The ports of a clock (default: the calling thread's, see `clock.current`), made on
    first use."""
    key = clock.current() if sim_clock is None else sim_clock
    with _PORTS_LOCK:
        ports = _PORTS.get(key)
        if ports is None:
            ports = _PORTS[key] = MemoryPorts()
        return ports


class MemoryEndpoint:
    """Serves one twin as ``mem://name``, one host at a time, like a serial cable (and like
    `SerialEndpoint`, whose `url`, `start`, `stop`, `twin`, `bytes_sent` and `refused` it
    shares): an open while another link holds the line is refused; closing makes room; each
    open is a fresh cable to the twin (`on_connect`)."""

    def __init__(self, twin: ByteTwin, name: str, ports: MemoryPorts | None = None):
        self.twin = twin
        self.name = name
        self.ports = ports_of() if ports is None else ports
        self._lock = threading.Lock()        # the twin is one device: one caller at a time
        self._host: MemoryLink | None = None
        self.bytes_sent = 0
        self.refused = 0                     # opens refused while another host held the line
        self.connects = 0
        self.ports._add(self)

    @property
    def url(self) -> str:
        return f"{MEMORY_SCHEME}://{self.name}"

    @property
    def host(self) -> MemoryLink | None:
        """The link that holds the line, if any."""
        return self._host

    def start(self) -> MemoryEndpoint:
        log.info("%s serving on %s", self.name, self.url)
        return self

    def stop(self) -> None:
        """Stop serving: the name is free again, and a host still on the line fails."""
        self.hang_up()
        self.ports._remove(self)

    def hang_up(self) -> None:
        """Drop the host, as a process that dies drops its socket: the line is free at once,
        and the old link's next read or write fails."""
        with self._lock:
            host, self._host = self._host, None
        if host is not None:
            host._wake_reader()
            log.info("%s: host hung up", self.name)

    # -- what MemoryLink calls ---------------------------------------------------------------
    def _connect(self, link: MemoryLink) -> None:
        with self._lock:
            if self._host is not None and self._host is not link:
                self.refused += 1
                raise serial.SerialException(f"{self.url}: another host holds the line "
                                             f"(one at a time, as on a serial port)")
            self._host = link
            self.connects += 1
            self.twin.on_connect(clock.monotonic())
        log.info("%s: host connected", self.name)

    def _disconnect(self, link: MemoryLink) -> None:
        with self._lock:
            if self._host is not link:
                return
            self._host = None
        log.info("%s: host disconnected", self.name)

    def _feed(self, link: MemoryLink, data: bytes) -> None:
        with self._lock:
            self._check(link)
            self.twin.feed(data, clock.monotonic())

    def _poll(self, link: MemoryLink) -> tuple[bytes, int]:
        """What the twin has sent by now, and (if nothing) in how many ns it is next due."""
        with self._lock:
            self._check(link)
            now = clock.monotonic_ns() / 1e9
            out = self.twin.poll(now)
            if out:
                self.bytes_sent += len(out)
                return out, 0
            return b"", math.ceil((self.twin.next_due(now) - now) * 1e9)

    def _check(self, link: MemoryLink) -> None:
        if self._host is not link:
            raise serial.SerialException(f"{self.url}: the line was hung up")


class MemoryLink(Link):
    """The host's end of a `MemoryEndpoint`, opened by ``mem://NAME`` (see the module
    docstring). Like ``socket://``: the rate is the host's business only, breaks do not
    reach the device, chunks are stamped when the read returns and hold at most CHUNK bytes."""

    def __init__(self, url: str, baudrate: int = DEFAULT_BAUDRATE, ports: MemoryPorts | None = None):
        super().__init__(url, baudrate)
        self.name = url.partition("://")[2]
        self._ports = ports                  # None: the opening thread's (ports_of)
        self._endpoint: MemoryEndpoint | None = None
        self._wake: Any = None               # a clock Event, set by writes and by closing
        self._held = bytearray()             # polled beyond CHUNK, for the next read

    @property
    def is_open(self) -> bool:
        return self._endpoint is not None

    def _open(self) -> None:
        ports = ports_of() if self._ports is None else self._ports
        endpoint = ports.endpoint(self.name)
        self._held.clear()
        self._wake = clock.Event()
        endpoint._connect(self)
        self._endpoint = endpoint

    def _read(self, timeout_s: float) -> bytes:
        """Poll the twin; while it has nothing, wait (in whole ns, as a virtual clock counts)
        until it is due, a write comes, or the timeout: then say so without asking again."""
        if self._held:
            return self._take()
        wait_ns = max(round(timeout_s * 1e9), MIN_WAIT_NS) if timeout_s > 0 else 0
        deadline_ns = clock.monotonic_ns() + wait_ns
        while True:
            endpoint, wake = self._endpoint, self._wake
            if endpoint is None:
                raise serial.SerialException(f"{self.url}: closed while reading")
            wake.clear()            # before the poll: a write after it wakes the wait below
            out, due_ns = endpoint._poll(self)
            if out:
                self._held += out
                return self._take()
            left_ns = deadline_ns - clock.monotonic_ns()
            if left_ns <= 0:
                return b""
            if due_ns > left_ns:    # not due before the deadline: only a write can change that
                if not wake.wait(left_ns / 1e9):
                    return b""
            else:
                wake.wait(max(due_ns, MIN_WAIT_NS) / 1e9)

    def _take(self) -> bytes:
        data = bytes(self._held[:CHUNK])
        del self._held[:CHUNK]
        return data

    def _write(self, data: bytes) -> None:
        endpoint = self._endpoint
        if endpoint is None:
            raise serial.PortNotOpenError()
        endpoint._feed(self, data)
        self._wake_reader()         # the twin may have answered at once

    def send_break(self, duration_s: float) -> None:
        """As pyserial's socket://: the break takes its time and goes nowhere."""
        clock.sleep(duration_s)

    def _wake_reader(self) -> None:
        wake = self._wake
        if wake is not None:
            wake.set()

    def _close(self) -> None:
        endpoint, self._endpoint = self._endpoint, None
        if endpoint is not None:
            endpoint._disconnect(self)
        self._wake_reader()
