"""Shared fixtures: a router on a free port, client sessions, and processes that are
always cleaned up (tests stop only what they start, by pid). Helpers: vienatest.py."""
from __future__ import annotations

import os

import pytest

from vienatest import Processes, free_port, wait_for_port


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


@pytest.fixture
def clean_env(tmp_path, monkeypatch):
    """A private run directory for compose profiles."""
    monkeypatch.setenv("VIENA_RUN", str(tmp_path / "run"))
    monkeypatch.delenv("VIENA_ROUTER_PORT", raising=False)
    return dict(os.environ)
