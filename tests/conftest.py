"""Shared fixtures: a router on a free port, client sessions, and processes that are
always cleaned up (tests stop only what they start, by pid). Helpers: vienatest.py."""
from __future__ import annotations

import os

import pytest
from vienatest import Processes, open_session, start_router


def pytest_collection_modifyitems(items):
    """A test that starts processes through `procs` (as `router` and `session` do) belongs
    to the slow tier: `-m "not slow"` leaves it out without a mark of its own."""
    for item in items:
        if "procs" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def procs():
    p = Processes()
    yield p
    p.stop_all()


@pytest.fixture
def router(procs):
    """A `viena router` on a free port; yields its endpoint."""
    return start_router(procs)


@pytest.fixture
def session(router):
    """A zenoh client session connected to the test router."""
    s = open_session(router)
    yield s
    s.close()


@pytest.fixture
def clean_env(tmp_path, monkeypatch):
    """A private run directory for compose profiles."""
    monkeypatch.setenv("VIENA_RUN", str(tmp_path / "run"))
    monkeypatch.delenv("VIENA_ROUTER_PORT", raising=False)
    return dict(os.environ)
