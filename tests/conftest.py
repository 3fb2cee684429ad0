"""Shared fixtures: a router on a free port, client sessions, and processes that are
always cleaned up (tests stop only what they start, by pid). Helpers: vienatest.py."""
from __future__ import annotations

import os

import pytest
from hypothesis import settings
from priority import WorkerPriority, forward_interrupts
from vienatest import Processes, open_session, start_router

# Property tests draw the same examples on every run, as every other test is the same on
# every run; a test's own @settings still say how many.
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")

#: how many whole cars may run at once on parallel workers (scripts/test): the first lane
#: takes the `car(realtime=True)` tests, the others (if any) the rest of the `car` tests
CAR_LANES = int(os.environ.get("VIENA_TEST_CARS", "1"))
#: what a `car` test is taken to last when its mark does not say (for sharing out the lanes)
CAR_SECONDS = 15.0
#: CPU priorities on a parallel worker (nice): the first lane's car (and the tests marked
#: `realtime`, which are not cars), then the other lanes' cars, then everything else
NICE_OF = {"first lane": 0, "other lanes": 3, "other": 5}
LANE = pytest.StashKey[int]()


@pytest.hookimpl(wrapper=True)         # around pytest-xdist's, which reads the xdist_group marks
def pytest_collection_modifyitems(config, items):
    """Tiers, and how a parallel run shares out the tests (docs/testing.md#parallel).

    - A test that starts processes through `procs` (as `router` and `session` do) belongs
      to the slow tier: `-m "not slow"` leaves it out without a mark of its own.
    - Tests marked `car` bring up a whole simulated car, which takes about two thirds of
      a core here: more cars at once than the cores carry make every real-time test on them late
      and trip the car's own watchdogs. They go to CAR_LANES lanes (xdist groups, each
      run in order on one worker), whole modules at a time: the tests whose figures are
      the car's real-time behaviour (`car(realtime=True)`) to the first lane, the others
      to the other lanes, the longest first to the least loaded; the other workers take
      everything else.
    - Other tests sharing a module-scoped fixture of ours (a key store, a router) go to
      one worker together, so that the fixture is made once.
    - The lanes start first (the real-time tests first in theirs), then the tests marked
      `realtime` (processes with watchdogs, but not a whole car: they run at the first
      lane's priority, on the other workers, before those lower theirs), then the other
      slow modules, then the quick ones, which fill the gaps at the end.
    - Each worker runs at its tests' CPU priority (pytest_runtest_setup, priority.py).
    """
    for item in items:
        if "procs" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
    lane_of = _car_lanes(items)
    if config.pluginmanager.hasplugin("xdist"):         # not with -p no:xdist: one process
        for item in items:
            if item.get_closest_marker("car"):
                item.stash[LANE] = lane_of[_module(item)]
                item.add_marker(pytest.mark.xdist_group(f"car-lane-{item.stash[LANE]}"))
            elif _shares_a_module_fixture(item):
                item.add_marker(pytest.mark.xdist_group(_module(item)))
    # Car tests first, lane by lane (a worker's priority is set by its first work unit and
    # cannot be raised again), the real-time ones first in theirs; then the tests marked
    # `realtime`, then the others, a module's slow ones before the quick. Stable: a
    # module's tests stay together.
    tier: dict[str, int] = {}
    for item in items:
        if not item.get_closest_marker("car"):
            tier[_module(item)] = min(tier.get(_module(item), 2), 1 if item.get_closest_marker("slow") else 2)

    def start(item) -> tuple:
        if item.get_closest_marker("car"):
            return (0, lane_of[_module(item)], not _realtime_car(item))
        if item.get_closest_marker("realtime"):
            return (1, 0, False)
        return (1 + tier[_module(item)], 0, False)
    items.sort(key=start)
    return (yield)


def pytest_configure(config):
    if getattr(config.option, "numprocesses", None) and not os.environ.get("PYTEST_XDIST_WORKER"):
        forward_interrupts()              # the workers are sessions of their own (priority.py)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """On a parallel worker, each test runs at its kind's CPU priority (NICE_OF), and so do
    the processes it starts, cars included (tests/priority.py): the cars run in real time
    and must keep up, the real-time lane's first; the others only take longer."""
    global _priority
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker:
        _priority = _priority or WorkerPriority(worker)
        _priority.lower_to(NICE_OF[_kind(item)])


def _kind(item) -> str:
    lane = item.stash.get(LANE, None)
    if lane is None:
        return "first lane" if item.get_closest_marker("realtime") else "other"
    return "first lane" if lane == 0 else "other lanes"


_priority: WorkerPriority | None = None


def _module(item) -> str:
    return item.nodeid.split("::")[0]


def _realtime_car(item) -> bool:
    mark = item.get_closest_marker("car")
    return bool(mark and mark.kwargs.get("realtime"))


def _car_lanes(items) -> dict[str, int]:
    """Module -> lane, for modules with `car` tests: real-time ones to lane 0, the others
    (with two lanes or more) longest first to the least loaded of the other lanes."""
    seconds: dict[str, float] = {}
    lane_of = {}
    for item in items:
        mark = item.get_closest_marker("car")
        if _realtime_car(item):
            lane_of[_module(item)] = 0
        elif mark:
            seconds[_module(item)] = seconds.get(_module(item), 0.0) + mark.kwargs.get("seconds", CAR_SECONDS)
    load = [0.0] * max(CAR_LANES - 1, 1)
    for module in sorted(seconds, key=seconds.get, reverse=True):
        lane = load.index(min(load))
        lane_of[module] = lane + (CAR_LANES > 1)
        load[lane] += seconds[module]
    return lane_of


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


@pytest.fixture(scope="module")
def zrouter():
    """A `viena router` on a free port for a whole module (its services as processes);
    yields its endpoint."""
    procs = Processes()
    yield start_router(procs)
    procs.stop_all()


@pytest.fixture(scope="module")
def zsession(zrouter):
    """A zenoh client session on the module's router."""
    s = open_session(zrouter)
    yield s
    s.close()


@pytest.fixture
def clean_env(tmp_path, monkeypatch):
    """A private run directory for compose profiles."""
    monkeypatch.setenv("VIENA_RUN", str(tmp_path / "run"))
    monkeypatch.delenv("VIENA_ROUTER_PORT", raising=False)
    return dict(os.environ)
