"""Shared fixtures: a router on a free port, client sessions, and processes that are
always cleaned up (tests stop only what they start, by pid)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from viena.common.measure import free_port, wait_for_port  # noqa: F401  (tests import them from here)

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


@pytest.fixture
def procs():
    p = Processes()
    yield p
    p.stop_all()


@pytest.fixture
def router(procs):
    """A `viena router` on a free port; yields its endpoint."""
    port = free_port()
    procs.python("-m", "viena.router", "--listen", f"tcp/127.0.0.1:{port}", "--log-level", "WARNING")
    wait_for_port(port)
    return f"tcp/127.0.0.1:{port}"


@pytest.fixture
def session(router):
    """A zenoh client session connected to the test router."""
    from viena.common.config import load_zenoh_config
    import zenoh

    s = zenoh.open(load_zenoh_config(mode="client", connect=[router]))
    yield s
    s.close()


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


def write_json(path, obj) -> None:
    path.write_text(json.dumps(obj))


@pytest.fixture
def clean_env(tmp_path, monkeypatch):
    """A private run directory for compose profiles."""
    monkeypatch.setenv("VIENA_RUN", str(tmp_path / "run"))
    monkeypatch.delenv("VIENA_ROUTER_PORT", raising=False)
    return dict(os.environ)
