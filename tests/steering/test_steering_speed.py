"""The car's speed as the steering envelope uses it (model/speed.py): the estimator's, with
its margin, checked by the GNSS receivers; bad samples refused and counted; the conservative
speed, with its reason, whenever the sources are stale or disagree."""
from __future__ import annotations

import math

import pytest

from viena.services.steering.model.speed import CONSERVATIVE, ESTIMATOR, REFUSALS, SpeedSettings, SpeedSources

S = SpeedSettings()                     # 0.5 s timeout, 15 m/s conservative, 2 sigmas margin
NOW = 100.0                             # monotonic seconds
WALL = 1_700_000_000_000_000_000        # the host's UTC time then (ns)


def estimator(sources: SpeedSources, speed, sigma=0.1, *, now=NOW, age_s=0.0, t_ns=None, valid=True) -> str:
    wall = WALL + round((now - NOW) * 1e9)
    t = wall - round(age_s * 1e9) if t_ns is None else t_ns
    return sources.estimator(t, speed, sigma, valid, now, wall)


def gnss(sources: SpeedSources, unit, speed, sigma=0.1, *, now=NOW, age_s=0.0, t_ns=None, valid=True) -> str:
    wall = WALL + round((now - NOW) * 1e9)
    t = wall - round(age_s * 1e9) if t_ns is None else t_ns
    return sources.gnss(unit, t, speed, sigma, valid, now, wall)


def test_a_fresh_estimator_speed_is_used_with_its_margin():
    sources = SpeedSources(S)
    assert estimator(sources, 10.0, 0.2) == ""
    assert sources.speed(NOW).mps == pytest.approx(10.4)                 # 10 + 2 * 0.2
    speed = sources.speed(NOW + S.speed_timeout_s)
    assert (speed.source, speed.problem) == (ESTIMATOR, "") and speed.mps == pytest.approx(10.4)


def test_without_a_fresh_estimator_speed_the_conservative_one_is_used_and_said():
    sources = SpeedSources(S)
    speed = sources.speed(NOW)
    assert (speed.mps, speed.source, speed.problem) == (15.0, CONSERVATIVE, "no speed from the estimator yet")
    estimator(sources, 3.0)
    late = sources.speed(NOW + S.speed_timeout_s + 0.01)              # by when it was received
    assert (late.mps, late.source) == (15.0, CONSERVATIVE)
    assert late.problem == "no fresh speed from the estimator for 0.51 s"
    estimator(sources, 3.0, now=NOW + 1.0)                            # back
    assert sources.speed(NOW + 1.0).source == ESTIMATOR


def test_a_receiver_alone_is_not_enough():
    """GNSS only checks the estimator: without it the speed is the conservative one."""
    sources = SpeedSources(S)
    gnss(sources, "gnss0", 2.0)
    assert sources.speed(NOW).source == CONSERVATIVE


@pytest.mark.parametrize("sample, cause", [
    (dict(speed=math.nan), "non_finite"),
    (dict(speed=math.inf), "non_finite"),
    (dict(speed=5.0, sigma=math.nan), "non_finite"),
    (dict(speed=True), "non_finite"),
    (dict(speed="5"), "non_finite"),
    (dict(speed=5.0, t_ns=float(WALL)), "non_finite"),
    (dict(speed=-0.5), "negative"),
    (dict(speed=5.0, sigma=-0.1), "negative"),
    (dict(speed=200.0), "absurd"),
    (dict(speed=70.1), "absurd"),
    (dict(speed=5.0, age_s=-0.25), "future"),
    (dict(speed=5.0, age_s=0.6), "stale"),
    (dict(speed=5.0, valid=False), "not_valid"),
])
def test_bad_samples_are_refused_by_cause_and_keep_nothing(sample, cause):
    assert cause in REFUSALS
    for feed in (estimator, lambda s, *a, **k: gnss(s, "gnss0", *a, **k)):
        sources = SpeedSources(S)
        assert feed(sources, **sample) == cause
        assert sources.refused == {cause: 1}
        assert sources.speed(NOW).source == CONSERVATIVE


def test_the_limits_of_what_is_taken():
    sources = SpeedSources(S)
    assert estimator(sources, 70.0) == ""                             # absurd is above 70
    assert estimator(sources, 0.0, 0.0) == ""
    assert estimator(sources, 5.0, age_s=-0.19) == ""                 # a clock 0.19 s ahead
    assert estimator(sources, 5.0, age_s=0.49) == ""
    assert sources.refused == {}


def test_a_bad_sample_does_not_replace_the_last_good_one_which_still_times_out():
    sources = SpeedSources(S)
    estimator(sources, 4.0, 0.0)
    for t in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6):
        estimator(sources, math.nan, now=NOW + t)
        estimator(sources, 200.0, now=NOW + t)
    assert sources.speed(NOW + 0.5).mps == 4.0
    assert sources.speed(NOW + 0.6).source == CONSERVATIVE
    assert sources.refused == {"non_finite": 6, "absurd": 6}


def test_agreeing_receivers_are_named_and_the_highest_speed_is_used():
    sources = SpeedSources(S)
    estimator(sources, 10.0, 0.1)                                     # 10.2
    gnss(sources, "gnss0", 10.3, 0.15)                                # 10.6
    gnss(sources, "gnss1", 9.9, 0.1)                                  # 10.1
    speed = sources.speed(NOW)
    assert speed.source == "estimator+gnss0+gnss1" and speed.mps == pytest.approx(10.6) and not speed.problem


def test_a_receiver_that_disagrees_gives_the_conservative_speed_and_names_both():
    sources = SpeedSources(S)
    estimator(sources, 4.0, 0.1)
    gnss(sources, "gnss0", 4.5, 0.1)
    gnss(sources, "gnss1", 9.0, 0.1)
    speed = sources.speed(NOW)
    assert (speed.mps, speed.source) == (15.0, CONSERVATIVE)
    assert speed.problem.startswith("the estimator's 4.0 m/s and gnss1's 9.0 m/s disagree")


def test_a_stale_receiver_is_left_out_not_counted_as_disagreeing():
    sources = SpeedSources(S)
    gnss(sources, "gnss0", 9.0)
    estimator(sources, 4.0, now=NOW + 0.6)
    assert sources.speed(NOW + 0.6).source == ESTIMATOR


def test_the_agreement_allows_what_the_car_can_accelerate_between_the_stamps():
    """4 sigmas of both (0.57 m/s) + the floor (0.5) + 4 m/s^2 * the time between the stamps."""
    sources = SpeedSources(S)
    estimator(sources, 5.0, 0.1)
    gnss(sources, "gnss0", 6.2, 0.1, age_s=0.3)                      # 1.2 apart, 1.07 + 1.2 allowed
    assert sources.speed(NOW).source == "estimator+gnss0"
    gnss(sources, "gnss0", 6.2, 0.1)                                  # the same, stamped with it: 1.07
    assert sources.speed(NOW).source == CONSERVATIVE


def test_a_fixs_speed_along_the_ground_is_pymap3ds_east_and_north():
    import random

    import pymap3d

    from viena.services.steering.service import horizontal_speed

    rng = random.Random(7)
    for _ in range(200):
        lat, lon = rng.uniform(-89.0, 89.0), rng.uniform(-180.0, 180.0)
        vel = tuple(rng.uniform(-40.0, 40.0) for _ in range(3))
        east, north, _ = pymap3d.uvw2enu(*vel, lat, lon)
        assert horizontal_speed(vel, lat, lon) == pytest.approx(math.hypot(east, north), abs=1e-9)


def test_the_steering_service_loads_no_numpy():
    """numpy is 13 MB of resident memory in a process that needs none of it (the Pi's budget:
    60 MB a program, docs/deployment.md)."""
    import subprocess
    import sys

    probe = "import sys, viena.services.steering.service; print('numpy' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert (run.returncode, run.stdout.strip()) == (0, "False"), run.stderr
