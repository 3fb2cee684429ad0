"""What tests share besides fixtures: processes that are always cleaned up, collecting
samples. Imported as `vienatest` (a unique name: every tests/ folder sees it)."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from typing import Callable

from benchmarks.harness import free_port, wait_for_port  # noqa: F401  (tests import them from here)

PYTHON = sys.executable


class Processes:
    """Starts subprocesses and guarantees they are gone at the end of the test."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []

    def start(self, *args: str, **kw) -> subprocess.Popen:
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        kw.setdefault("text", True)
        proc = subprocess.Popen([str(a) for a in args], **kw)
        self.procs.append(proc)
        return proc

    def python(self, *args: str, **kw) -> subprocess.Popen:
        return self.start(PYTHON, *args, **kw)

    def stop_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self.procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def collect(session, keyexpr: str, count: int, timeout: float = 10.0, decode=None) -> list:
    """The first `count` samples on keyexpr (decoded by `decode` if given)."""
    import queue

    q: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(keyexpr, lambda s: q.put((str(s.key_expr), s.payload.to_bytes(), str(s.encoding))))
    out = []
    end = time.monotonic() + timeout
    try:
        while len(out) < count and time.monotonic() < end:
            try:
                key, payload, enc = q.get(timeout=0.1)
            except queue.Empty:
                continue
            out.append(decode(payload) if decode else (key, payload, enc))
    finally:
        sub.undeclare()
    return out


def wait_until(predicate: Callable[[], bool], timeout: float, period: float = 0.01) -> bool:
    """Poll `predicate` until true or `timeout` s pass; for tests and start-up waits."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())
