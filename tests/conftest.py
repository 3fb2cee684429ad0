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

#: how many whole cars may run at once on parallel workers (scripts/test)
CAR_LANES = int(os.environ.get("VIENA_TEST_CARS", "1"))
#: what a `car` test is taken to last when its mark does not say (for sharing out the lanes)
CAR_SECONDS = 15.0


@pytest.hookimpl(wrapper=True)         # around pytest-xdist's, which reads the xdist_group marks
def pytest_collection_modifyitems(config, items):
    """Tiers, and how a parallel run shares out the tests (docs/testing.md#parallel).

    - A test that starts processes through `procs` (as `router` and `session` do) belongs
      to the slow tier: `-m "not slow"` leaves it out without a mark of its own.
    - Tests marked `car` bring up a whole simulated car, which takes about 60 % of a core
      here: more cars at once than the cores carry make every real-time test on them late
      and trip the car's own watchdogs. They go to CAR_LANES lanes (xdist groups, each
      run in order on one worker), whole modules at a time, the longest first to the
      least loaded lane; the other workers take everything else.
    - Other tests sharing a module-scoped fixture of ours (a key store, a router) go to
      one worker together, so that the fixture is made once.
    - The lanes start first, then the other slow modules, then the quick ones, which
      fill the gaps at the end.
    """
    for item in items:
        if "procs" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
    lane_of = _car_lanes(items)
    if config.pluginmanager.hasplugin("xdist"):         # not with -p no:xdist: one process
        for item in items:
            if item.get_closest_marker("car"):
                item.add_marker(pytest.mark.xdist_group(f"car-lane-{lane_of[_module(item)]}"))
            elif _shares_a_module_fixture(item):
                item.add_marker(pytest.mark.xdist_group(_module(item)))
    first: dict[str, int] = {}
    for item in items:
        first[_module(item)] = min(first.get(_module(item), 2), _start_order(item))
    items.sort(key=lambda item: (first[_module(item)], lane_of.get(_module(item), 0)))   # stable: modules stay whole
    return (yield)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """On a parallel worker, tests other than the cars' run at a lower CPU priority (and
    so do the processes they start): the cars run in real time and must keep up; the
    others only take longer."""
    if os.environ.get("PYTEST_XDIST_WORKER") and not item.get_closest_marker("car") and os.nice(0) < NICE:
        os.nice(NICE - os.nice(0))         # once, for good: a process cannot raise it again


#: the priority of tests other than the cars' on a parallel worker
NICE = 10


def _module(item) -> str:
    return item.nodeid.split("::")[0]


def _car_lanes(items) -> dict[str, int]:
    """Module -> lane, for modules with `car` tests: longest first to the least loaded lane."""
    seconds: dict[str, float] = {}
    for item in items:
        mark = item.get_closest_marker("car")
        if mark:
            seconds[_module(item)] = seconds.get(_module(item), 0.0) + mark.kwargs.get("seconds", CAR_SECONDS)
    load = [0.0] * max(CAR_LANES, 1)
    lane_of = {}
    for module in sorted(seconds, key=seconds.get, reverse=True):
        lane = load.index(min(load))
        lane_of[module] = lane
        load[lane] += seconds[module]
    return lane_of


def _shares_a_module_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    return info is not None and any(
        d.scope != "function" and d.baseid          # ours (pytest's own have no baseid)
        for defs in info.name2fixturedefs.values() for d in defs)


def _start_order(item) -> int:
    if item.get_closest_marker("car"):
        return 0
    return 1 if item.get_closest_marker("slow") else 2


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
