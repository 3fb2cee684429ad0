"""Keeping one device going whatever it does: connect, serve, notice a failed port or a
silence, close, and connect again after a backoff, so data flows again soon after the
device comes back.

Every device service runs one `DeviceSupervisor` over its own `Device` (the few things a
supervisor needs from a driver) and reports under the fixed names of common/samples/health.py:
``reconnects`` (counts), ``connect_failures``, ``port_failures``, ``silences``,
``internal_errors`` (errors), ``connected``, ``last_error``, ``port`` (state). The
supervisor knows neither zenoh nor bytes: the service hands it a `Health`, a
`SilenceWatch` and the device.

The policy: the first attempt at once; after a failed one wait ``first_s``, doubling up to
``max_s``; after the device was lost, try again at once (it is usually back, or was never
really gone). A device that raises something unexpected is logged with its traceback,
counted, and reopened after ``max_s``: a bug must neither end the service nor spin.
"""
from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from typing import Any

from viena.common import clock
from viena.common.health import Health
from viena.common.samples.health import (
    CONNECT_FAILURES,
    CONNECTED,
    DEVICE_ERRORS,
    INTERNAL_ERRORS,
    LAST_ERROR,
    PORT,
    PORT_FAILURES,
    RECONNECTS,
    SILENCES,
)
from viena.common.silence import SilenceWatch

log = logging.getLogger(__name__)


class Device(ABC):
    """A device as the supervisor sees it; each service adapts its driver to this."""

    #: what the supervisor calls it in the log
    kind = "device"
    #: what a failed attempt to connect raises (anything else counts as an internal error)
    connect_errors: tuple[type[BaseException], ...] = (OSError,)

    @abstractmethod
    def connect(self, again: bool) -> None:
        """Open and start the device; `again` once it has been lost (a quicker way back
        may be tried first)."""

    @abstractmethod
    def serve(self, timeout_s: float) -> None:
        """Handle what the device sends for up to `timeout_s` (or only wait, when a reader
        thread handles it), telling the silence watch what was heard. Raise OSError when
        the port has failed."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the device. Also called from another thread to wake a connect or serve
        that is stuck on the port."""

    def shutdown(self) -> None:
        """The service is stopping: leave the device tidy, and closed."""
        self.disconnect()

    def counters(self) -> tuple[dict[str, int], dict[str, int]]:
        """The driver's running totals since start, (counts, errors); health gets them as
        increments so that its rates work."""
        return {}, {}


class Backoff:
    """Waits between attempts: `first_s`, doubling each time, never more than `max_s`."""

    def __init__(self, first_s: float = 0.05, max_s: float = 0.5):
        self.first_s, self.max_s = first_s, max_s
        self._next_s = first_s

    def next_s(self) -> float:
        delay = min(self._next_s, self.max_s)
        self._next_s = delay * 2
        return delay

    def reset(self) -> None:
        self._next_s = self.first_s


class DeviceSupervisor:
    """Runs a device on a thread of its own (`start`/`stop`), or in the caller (`run`)."""

    def __init__(self, device: Device, health: Health, silence: SilenceWatch, *, url: str,
                 backoff: Backoff | None = None, tick_s: float = 0.1,
                 stopping: Any = None):
        self.device, self.health, self.silence = device, health, silence
        self.url = url
        self.backoff = backoff or Backoff()
        self.tick_s = tick_s
        self.stopping = stopping or clock.Event()
        self._pushed: dict[str, int] = {}
        self._thread: Any = None
        self._show_every_counter()

    # -- the thread ----------------------------------------------------------------------
    def start(self) -> DeviceSupervisor:
        self._thread = clock.Thread(target=self.run, name=f"{self.device.kind}-supervisor",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self, join_s: float = 0.7) -> None:
        """Let the supervisor shut the device down; if it is stuck on the port, close the
        device under it so that it gives up at once."""
        self.stopping.set()
        thread = self._thread
        if thread is None:
            return
        thread.join(timeout=join_s)
        if thread.is_alive():
            self.device.disconnect()
            thread.join(timeout=join_s)

    # -- the life of the device ----------------------------------------------------------
    def run(self) -> None:
        """Connect, serve and reconnect until `stopping` is set; then shut the device down."""
        connected_once, failed_attempts = False, 0
        while not self.stopping.is_set():
            if not self._attempt(again=connected_once, loud=failed_attempts == 0):
                failed_attempts += 1
                self.stopping.wait(self.backoff.next_s())
                continue
            if connected_once:
                self.health.count(RECONNECTS)
                log.info("%s: %s connected again (after %d failed attempts)", self.url,
                         self.device.kind, failed_attempts)
            else:
                log.info("%s: %s connected", self.url, self.device.kind)
            connected_once, failed_attempts = True, 0
            reason = self._serve()
            if reason is None:
                break
            self.health.set(LAST_ERROR, reason)
            log.warning("%s: %s; reconnecting", self.url, reason)
            self.device.disconnect()
        self._shutdown()

    def _attempt(self, again: bool, loud: bool) -> bool:
        """One try at connecting; a failure is counted, shown and logged (`loud`: as a
        warning, else quietly)."""
        try:
            self.device.connect(again)
        except Exception as exc:  # noqa: BLE001 - sorted below: the device's or a bug
            self.device.disconnect()
            self._report()
            if self.stopping.is_set():
                return False
            expected = isinstance(exc, self.device.connect_errors)
            self.health.error(CONNECT_FAILURES if expected else INTERNAL_ERRORS)
            self.health.set(LAST_ERROR, str(exc) or type(exc).__name__)
            if loud:
                log.warning("%s: cannot connect the %s: %s (retrying)", self.url,
                            self.device.kind, exc, exc_info=not expected)
            else:
                log.debug("%s: still cannot connect: %s", self.url, exc)
            return False
        return True

    def _serve(self) -> str | None:
        """Serve the connected device until it is lost (the reason) or we stop (None)."""
        self.health.set(CONNECTED, True)
        self.backoff.reset()
        self.silence.restart()
        try:
            while not self.stopping.is_set():
                reason = self._serve_once()
                self._report()
                if reason is not None:
                    return reason
            return None
        finally:
            self.health.set(CONNECTED, False)

    def _serve_once(self) -> str | None:
        """One tick: why the device is lost, or None while it is fine (or we stop)."""
        try:
            self.device.serve(self.tick_s)
        except OSError as exc:
            if self.stopping.is_set():
                return None                 # closed under it by stop()
            self.health.error(PORT_FAILURES)
            return f"port failed ({str(exc) or type(exc).__name__})"
        except Exception as exc:  # noqa: BLE001 - a bug must not end the service
            log.exception("%s: serving the %s failed", self.url, self.device.kind)
            self.health.error(INTERNAL_ERRORS)
            self.device.disconnect()
            self.stopping.wait(self.backoff.max_s)         # nor make it spin
            return f"internal error ({exc!r})"
        if self.silence.expired():
            self.health.error(SILENCES)
            return f"silent for {self.silence.quiet_s():.1f} s"
        return None

    def _shutdown(self) -> None:
        self._report()
        try:
            self.device.shutdown()
        except Exception as exc:  # noqa: BLE001 - closing is best effort
            log.debug("%s: shutdown: %s", self.url, exc)
        self.health.set(CONNECTED, False)

    # -- health --------------------------------------------------------------------------
    def _show_every_counter(self) -> None:
        """Every name at zero from the start: a counter that never moved is still shown."""
        self.health.set(PORT, self.url)
        self.health.set(CONNECTED, False)
        self.health.count(RECONNECTS, 0)
        counts, errors = self.device.counters()
        for name in counts:
            self.health.count(name, 0)
        for name in (*DEVICE_ERRORS, *errors):
            self.health.error(name, 0)

    def _report(self) -> None:
        """Move the driver's running totals into health, as increments."""
        counts, errors = self.device.counters()
        for table, bump in ((counts, self.health.count), (errors, self.health.error)):
            for name, total in table.items():
                delta = total - self._pushed.get(name, 0)
                if delta > 0:
                    bump(name, delta)
                    self._pushed[name] = total
