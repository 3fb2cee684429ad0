"""The NTRIP client's life: connect, stream, and try again when the caster allows it.

One thread (`viena.common.clock.Thread`) runs `NtripClient.run`: wait as the RetryPolicy
says, open a link (driver/caster.py), read the stream, frame it (driver/rtcm3.py, or
RAW), hand each read's batch to `on_batch`, send the car's position upstream (GGA) every
``gga_interval_s``, and end the stream after ``inactivity_s`` without data. Every wait and
every time read goes through viena.common.clock, so tests run the loop on a virtual clock
with a scripted link (`open_link`).

What a person needs to see is kept in `status()` (the service publishes it as
viena.ntrip.state/1): state, why, next attempt, counters, rates, base station, and the
error counters (`errors`), one per kind of bad input, which the service adds to health.
Nothing here logs or keeps the password: the link gets the credentials, re-read from their
file at every attempt (a fixed file is taken without a restart).
"""
from __future__ import annotations

import logging
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from viena.common import clock
from viena.common.log import Throttled
from viena.services.ntrip.driver.caster import CasterAddress, CasterLink, LinkError
from viena.services.ntrip.driver.credentials import Credentials, CredentialsError, read_credentials
from viena.services.ntrip.driver.protocol import NtripProtocol, Position
from viena.services.ntrip.driver.retry import RetryPolicy
from viena.services.ntrip.driver.rtcm3 import Batch, Rtcm3Framer

#: how often the stream loop looks up from the socket (stop, GGA, inactivity)
READ_POLL_S = 0.5
#: bytes/s is over this window
RATE_WINDOW_S = 10.0
#: the same failure, repeated, is logged once in this long (with how many came meanwhile)
REPEAT_LOG_S = 600.0
#: garbage between frames is logged once in this long
GARBAGE_LOG_S = 60.0


@dataclass(frozen=True)
class ClientConfig:
    """What the client needs besides the caster's address."""

    address: CasterAddress
    #: "": no login (an open caster)
    credentials_file: str = ""
    #: RTCMV3: whole checked frames; RAW: the bytes as they come
    format: str = "RTCMV3"
    #: 0: never send the position upstream
    gga_interval_s: float = 0.0
    #: no data for this long on an open stream: close it, and try again
    inactivity_s: float = 10.0
    #: the longest wait for the TCP connection and for the caster's answer
    connect_timeout_s: float = 10.0


class RateWindow:
    """Bytes per second over the last `window_s` seconds (times given by the caller)."""

    def __init__(self, window_s: float = RATE_WINDOW_S):
        self.window_s = window_s
        self._events: deque[tuple[float, int]] = deque()
        self._sum = 0

    def add(self, now: float, n: int) -> None:
        self._events.append((now, n))
        self._sum += n
        self._trim(now)

    def rate(self, now: float) -> float:
        self._trim(now)
        return self._sum / self.window_s

    def _trim(self, now: float) -> None:
        while self._events and self._events[0][0] <= now - self.window_s:
            self._sum -= self._events.popleft()[1]


OpenLink = Callable[[ClientConfig, "Credentials | None", "Position | None", NtripProtocol], Any]


def open_caster_link(config: ClientConfig, credentials: Credentials | None, position: Position | None,
                     protocol: NtripProtocol) -> CasterLink:
    """The real link: a socket to the caster, opened (LinkError when it is not the stream)."""
    link = CasterLink(config.address, credentials, protocol, position=position,
                      timeout_s=config.connect_timeout_s)
    try:
        link.open()
    except BaseException:
        link.close()
        raise
    return link


class NtripClient:
    """See the module docstring. `start()` / `stop()`, or `run()` in the caller's thread."""

    def __init__(self, config: ClientConfig, *, on_batch: Callable[[Batch], None],
                 on_change: Callable[[], None] = lambda: None,
                 position: Callable[[], Position | None] = lambda: None,
                 policy: RetryPolicy | None = None, open_link: OpenLink = open_caster_link,
                 log: logging.Logger | None = None):
        self.config = config
        self.on_batch, self.on_change, self.position = on_batch, on_change, position
        self.policy = policy or RetryPolicy()
        self.open_link = open_link
        self.log = log or logging.getLogger("viena.ntrip")
        self.protocol = NtripProtocol()
        self.framer = Rtcm3Framer() if config.format == "RTCMV3" else None
        self.stopping = clock.Event()
        self._lock = threading.Lock()
        self._thread: Any = None
        self._link: Any = None
        self._repeats = Throttled(self.log, config.address.source, REPEAT_LOG_S)
        self._garbage_log = Throttled(self.log, config.address.source, GARBAGE_LOG_S)
        self._internal_logged_at: float | None = None
        # what status() reports
        self.state = "waiting"
        self.why: str | None = None
        self.connected = False
        self.next_attempt_at: float | None = None
        self.attempts = 0
        self.connects = 0
        self.gga_sent = 0
        self.base_id: str | None = None
        self.last_message_at: float | None = None
        self.messages: Counter[int] = Counter()
        self.rate = RateWindow()
        #: kinds of bad input and failure, since start (the service adds them to health)
        self.errors: Counter[str] = Counter()
        #: good events since start: bytes, frames, batches
        self.counts: Counter[str] = Counter()

    # -- the thread ------------------------------------------------------------------------------
    def start(self) -> NtripClient:
        self._thread = clock.Thread(target=self.run, name="ntrip-client", daemon=True)
        self._thread.start()
        return self

    def stop(self, join_s: float = 1.5) -> None:
        self.stopping.set()
        link = self._link
        if link is not None:
            link.close()                     # wakes a read stuck on the socket
        if self._thread is not None:
            self._thread.join(timeout=join_s)

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                self._wait_and_attempt()
            except Exception as exc:  # noqa: BLE001 - a bug must not end the corrections for good
                self._internal_error(exc)
        self._set(state="stopped", connected=False, next_attempt_at=None)

    def _wait_and_attempt(self) -> None:
        now = clock.monotonic()
        wait = self.policy.wait_s(now)
        if wait > 0:
            self._set(state="refused" if self.state == "refused" else "waiting",
                      next_attempt_at=now + wait)
            if self.stopping.wait(wait):
                return
        self._attempt()

    def _internal_error(self, exc: Exception) -> None:
        """A bug outside an attempt's own guard: count it, say it (once in REPEAT_LOG_S, with
        its traceback), and wait as the policy says, but never less than its minimum
        interval, so a bug that recurs neither spins nor hammers the caster."""
        now = clock.monotonic()
        wait = max(self.policy.wait_s(now), self.policy.min_interval_s)
        with self._lock:
            self.errors["internal_errors"] += 1
            count = self.errors["internal_errors"]
            self.state, self.connected, self.next_attempt_at = "waiting", False, now + wait
            self.why = f"internal error: {type(exc).__name__}"
            due = self._internal_logged_at is None or now - self._internal_logged_at >= REPEAT_LOG_S
            if due:
                self._internal_logged_at = now
        if due:
            self.log.exception("%s: internal error in the connection loop (%d since start); next attempt "
                               "in %.0f s", self.config.address.source, count, wait)
        self.stopping.wait(wait)

    # -- one attempt -------------------------------------------------------------------------------
    def _attempt(self) -> None:
        started = clock.monotonic()
        self.policy.started(started)
        with self._lock:
            self.attempts += 1
        self._set(state="connecting", next_attempt_at=None)
        streamed_s, failure = 0.0, None
        try:
            credentials = self._credentials()
            position = self.position() if self.config.gga_interval_s > 0 else None
            link = self.open_link(self.config, credentials, position, self.protocol)
            self._link = link
            if self.stopping.is_set():
                return
            if position is not None:
                with self._lock:
                    self.gga_sent += 1
            with self._lock:
                self.connects += 1
            self._set(state="streaming", connected=True, why=None)
            self.log.info("%s: streaming (NTRIP %s%s)", self.config.address.source,
                          self.config.address.version, ", TLS" if self.config.address.tls else "")
            streamed_s = self._stream(link, gga_due=clock.monotonic() + (
                self.config.gga_interval_s if position is not None else 0.0))
        except LinkError as exc:
            failure, streamed_s = exc, exc.streamed_s
        except Exception as exc:  # noqa: BLE001 - a bug must not end the corrections for good
            self.log.exception("%s: internal error", self.config.address.source)
            failure = LinkError(f"internal error: {type(exc).__name__}: {exc}", "internal_errors")
        finally:
            link, self._link = self._link, None
            if link is not None:
                link.close()
            if self.framer is not None:
                left = self.framer.reset()
                if left:
                    self._count_garbage(left, "an incomplete frame at the end of the stream")
            ended = clock.monotonic()
            self.policy.ended(ended, streamed_s)
        if self.stopping.is_set():
            return
        if failure is None:
            failure = LinkError("stream ended", "dropped")
        self._failed(failure, streamed_s)

    def _credentials(self) -> Credentials | None:
        if not self.config.credentials_file:
            return None
        try:
            return read_credentials(self.config.credentials_file)
        except CredentialsError as exc:
            raise LinkError(str(exc), "credentials", refused=True) from None

    def _failed(self, failure: LinkError, streamed_s: float) -> None:
        why = failure.why
        if streamed_s > 0:
            why = f"{why} after {streamed_s:.0f} s of data"
        with self._lock:
            self.errors[failure.kind] += 1
        self._set(state="refused" if failure.refused else "waiting", connected=False, why=why,
                  next_attempt_at=self.policy.next_start())
        self._repeats.log(failure.why, f"attempt {self.attempts}; next in "
                                       f"{self.policy.wait_s(clock.monotonic()):.0f} s")

    # -- the stream --------------------------------------------------------------------------------
    def _stream(self, link, gga_due: float) -> float:
        """Read until the stream ends (LinkError, carrying how long data came) or the client
        stops (returns that)."""
        cfg = self.config
        first_data: float | None = None
        last_data = clock.monotonic()
        streamed = 0.0
        try:
            while not self.stopping.is_set():
                now = clock.monotonic()
                if cfg.gga_interval_s > 0 and now >= gga_due:
                    gga_due = now + (cfg.gga_interval_s if self._send_gga(link) else 1.0)
                data = link.read(READ_POLL_S)
                now = clock.monotonic()
                if data:
                    if first_data is None:
                        first_data = now
                    last_data, streamed = now, now - first_data
                    self._take(data, now)
                elif now - last_data > cfg.inactivity_s:
                    hint = ""
                    if cfg.gga_interval_s > 0 and self.gga_sent == 0:
                        hint = " (no GGA sent yet: no fix on the bus)"
                    raise LinkError(f"no data for {cfg.inactivity_s:g} s{hint}", "silences")
        except LinkError as exc:
            exc.streamed_s = streamed
            raise
        return streamed

    def _send_gga(self, link) -> bool:
        position = self.position()
        if position is None:
            return False
        link.send(self.protocol.gga(position))
        with self._lock:
            self.gga_sent += 1
        return True

    def _take(self, data: bytes, now: float) -> None:
        if self.framer is None:
            batch = Batch(data)
        else:
            batch = self.framer.feed_batch(data)
            if batch.garbage_bytes:
                self._count_garbage(batch.garbage_bytes, "bytes between RTCM 3 frames that are no frame")
        changed = False
        with self._lock:
            self.counts["bytes"] += len(data)
            if batch.data:
                self.rate.add(now, len(batch.data))
                self.last_message_at = now
                self.counts["batches"] += 1
                self.counts["frames"] += len(batch.types)
                self.messages.update(batch.types)
                if batch.base_id is not None and batch.base_id != self.base_id:
                    self.base_id, changed = batch.base_id, True
        if batch.data:
            self.on_batch(batch)
        if changed:
            self.log.info("%s: base station %s", self.config.address.source, batch.base_id)
            self.on_change()

    def _count_garbage(self, n: int, what: str) -> None:
        with self._lock:
            self.errors["garbage_bytes"] += n
        self._garbage_log.log("garbage skipped", f"{n} {what}; "
                                                 f"{self.errors['garbage_bytes']} bytes since start")

    # -- what a person sees ------------------------------------------------------------------------
    def _set(self, **changes) -> None:
        with self._lock:
            changed = any(getattr(self, k) != v for k, v in changes.items() if k != "next_attempt_at")
            for k, v in changes.items():
                setattr(self, k, v)
        if changed:
            self.on_change()

    def status(self) -> dict:
        """The state fields of viena.ntrip.state/1 (without t and seq)."""
        now = clock.monotonic()
        a = self.config.address
        with self._lock:
            return {
                "caster": a.caster, "mountpoint": a.mountpoint, "version": a.version, "tls": a.tls,
                "format": self.config.format, "connected": self.connected, "state": self.state,
                "why": self.why,
                "next_attempt_s": (None if self.next_attempt_at is None or self.state not in ("waiting", "refused")
                                   else max(self.next_attempt_at - now, 0.0)),
                "bytes_per_s": self.rate.rate(now),
                "messages": {str(k): v for k, v in sorted(self.messages.items())},
                "base_id": self.base_id,
                "last_message_age_s": None if self.last_message_at is None else now - self.last_message_at,
                "attempts": self.attempts, "connects": self.connects, "gga_sent": self.gga_sent,
            }
