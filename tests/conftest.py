"""Shared fixtures: a router on a free port, client sessions, and processes that are
always cleaned up (tests stop only what they start, by pid). Helpers: vienatest.py."""
from __future__ import annotations

import os

import pytest
from hypothesis import settings
from vienatest import Processes, open_session, start_router

# Property tests draw the same examples on every run, as every other test is the same on
# every run; a test's own @settings still say how many.
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")

#: the xdist group of the tests that bring up a whole car in real time: one at a time
CAR_LANE = "car-lane"


@pytest.hookimpl(wrapper=True)         # around pytest-xdist's, which reads the xdist_group marks
def pytest_collection_modifyitems(config, items):
    """Tiers, and how a parallel run shares out the tests (docs/testing.md#parallel).

    - A test that starts processes through `procs` (as `router` and `session` do) belongs
      to the slow tier: `-m "not slow"` leaves it out without a mark of its own.
    - Tests marked `car` bring up a whole simulated car as processes, in real time, which
      takes about two thirds of a core here: two at once on two cores would make each
      other late. They share one lane (an xdist group, run in order on one worker), whole
      modules at a time. What the car does is tested in virtual time
      (docs/lockstep.md), where no machine is too busy; these are the real-time tier.
    - Other tests sharing a module-scoped fixture of ours (a key store, a router) go to
      one worker together, so that the fixture is made once.
    - The lane starts first (it is the longest), then the other slow modules, then the
      quick ones, which fill the gaps at the end.
    """
    for item in items:
        if "procs" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
    if config.pluginmanager.hasplugin("xdist"):         # not with -p no:xdist: one process
        for item in items:
            if item.get_closest_marker("car"):
                item.add_marker(pytest.mark.xdist_group(CAR_LANE))
            elif _shares_a_module_fixture(item):
                item.add_marker(pytest.mark.xdist_group(_module(item)))
    tier: dict[str, int] = {}
    for item in items:
        tier[_module(item)] = min(tier.get(_module(item), 2), 1 if item.get_closest_marker("slow") else 2)

    def start(item) -> int:
        return 0 if item.get_closest_marker("car") else tier[_module(item)]
    items.sort(key=start)
    return (yield)


def _module(item) -> str:
    return item.nodeid.split("::")[0]


def _shares_a_module_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    return info is not None and any(
        d.scope != "function" and d.baseid          # ours (pytest's own have no baseid)
        for defs in info.name2fixturedefs.values() for d in defs)


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
