"""Reading a link on a thread of its own, for drivers whose bytes must be handled as they
come (a receiver that answers commands while it streams logs).

python-can's ``Notifier`` over a bus, for a `Link`: every chunk goes to
``on_data(data, t_host_ns)`` at once; a port that fails is reported once to
``on_error(exc)`` and the thread ends, so the owner decides what next. A consumer that
raises is logged and the reading goes on: its bug must not look like a lost device.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from viena.common import clock
from viena.common.link import Link

log = logging.getLogger(__name__)
#: marks a thread as one of the readers, so that `stop()` called from it does not join it
_local = threading.local()

#: how long one read may wait: bounds how long `stop()` takes
READ_TIMEOUT_S = 0.05


class LinkReader:
    """Pumps an open link's bytes to a callback until stopped or the port fails."""

    def __init__(self, link: Link, on_data: Callable[[bytes, int], None],
                 on_error: Callable[[Exception], None] | None = None, name: str = "link"):
        self.link = link
        self._on_data = on_data
        self._on_error = on_error
        self._name = name
        self._thread: Any = None                # a clock Thread
        self._stop = clock.Event()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> LinkReader:
        """Start reading the (open) link; a reader still running is stopped first."""
        self.stop()
        self._stop = clock.Event()     # the old thread keeps its own, already set
        self._thread = clock.Thread(target=self._run, args=(self._stop,),
                                    name=f"{self._name}-reader", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread (within READ_TIMEOUT_S); callable from the thread itself."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and getattr(_local, "reader", None) is not self:
            thread.join(timeout=1.0)

    def _run(self, stop: Any) -> None:
        _local.reader = self
        while not stop.is_set():
            try:
                data, t_host_ns = self.link.read(READ_TIMEOUT_S)
            except Exception as exc:  # noqa: BLE001 - any failure of the port ends the reading
                if not stop.is_set():
                    log.debug("%s: reader stopped: %r", self.link.url, exc)
                    if self._on_error is not None:
                        self._on_error(exc)
                return
            if data:
                try:
                    self._on_data(data, t_host_ns)
                except Exception:  # noqa: BLE001 - a consumer's bug must not end the link
                    log.exception("%s: handling received bytes failed", self.link.url)
