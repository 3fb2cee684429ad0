"""The pilot's precision rule (issue 28) on a simulated clock: which GNSS solution it follows
with, how old its corrections may be, stop or warn, and the hysteresis that keeps a
flickering solution from starting and stopping it."""
from __future__ import annotations

import pytest

from tests.pilot.test_pilot_core import T0, est, straight_north
from viena.common.display import Alert
from viena.common.errors import ConfigError
from viena.common.samples.fix import SOLUTION_KINDS, solution_rank
from viena.common.samples.pilot import STATE, monitor_view
from viena.common.settings import from_mapping
from viena.services.pilot.model.estimate import estimate_of
from viena.services.pilot.model.pilot import Pilot, PilotSettings
from viena.services.pilot.model.precision import Precision, PrecisionSettings
from viena.services.pilot.service import PilotServiceSettings

MS = 1_000_000
S = 1_000_000_000


def pilot_with(**precision) -> Pilot:
    pilot = Pilot(PilotSettings(precision=PrecisionSettings(**precision)))
    pilot.on_estimate(est(x=0.2, y=5.0, gnss_kind="single"))
    pilot.set_route(straight_north())
    return pilot


def drive(pilot: Pilot, t0: int, t1: int, **kw) -> int:
    """Ticks every 25 ms from t0 to t1 (ns) with a fresh estimate of solution `kw` each;
    returns t1."""
    t = t0
    while t < t1:
        pilot.on_estimate(est(t_ns=t, x=0.2, y=5.0, **kw))
        pilot.tick(t)
        t += 25 * MS
    return t1


def state(pilot: Pilot, now: int) -> dict:
    return STATE.decode(STATE.encode(pilot.snapshot(now, 0, False)))


def test_by_default_any_solution_is_followed_as_before():
    pilot = pilot_with()
    pilot.on_estimate(est(gnss_kind=None, x=0.2, y=5.0))        # an estimator that does not say
    assert pilot.start(T0) is None
    drive(pilot, T0, T0 + 2 * S, gnss_kind="single")
    assert pilot.mode == "following"
    s = state(pilot, T0 + 2 * S)
    assert s["precision_ok"] is True and s["precision_reason"] is None
    assert s["precision_kind"] == "single"                  # said, not judged


def test_start_needs_the_solution_held_for_a_second():
    pilot = pilot_with(min_solution="float")
    assert pilot.start(T0) == "solution single, the pilot needs float or better"
    t = drive(pilot, T0, T0 + 2 * S, gnss_kind="single", gnss_diff_age_s=None)
    assert pilot.start(t) == "solution single, the pilot needs float or better"
    t = drive(pilot, t, t + 500 * MS, gnss_kind="fixed", gnss_diff_age_s=1.0)
    assert pilot.start(t) == "solution fixed for 0.5 s, needs 1 s"
    t = drive(pilot, t, t + 600 * MS, gnss_kind="fixed", gnss_diff_age_s=1.0)
    assert pilot.start(t) is None and pilot.mode == "following"
    s = state(pilot, t)
    assert s["precision_ok"] is True and s["precision_kind"] == "fixed" and s["precision_diff_age_s"] == 1.0


def following_on_fixed(**precision) -> tuple[Pilot, int]:
    pilot = pilot_with(**precision)
    t = drive(pilot, T0, T0 + 2 * S, gnss_kind="fixed", gnss_diff_age_s=0.5)
    assert pilot.start(t) is None
    return pilot, t


def test_a_flicker_does_not_stop_it_a_lasting_fall_does():
    pilot, t = following_on_fixed(min_solution="fixed")
    t = drive(pilot, t, t + 300 * MS, gnss_kind="float", gnss_diff_age_s=0.5)     # one float spell
    t = drive(pilot, t, t + 2 * S, gnss_kind="fixed", gnss_diff_age_s=0.5)
    assert pilot.mode == "following"
    t = drive(pilot, t, t + 1100 * MS, gnss_kind="single", gnss_diff_age_s=None)  # corrections lost
    assert pilot.mode == "stopped"
    assert pilot.reason == "solution single, the pilot needs fixed"
    s = state(pilot, t)
    assert s["mode"] == "stopped" and s["precision_ok"] is False
    assert s["precision_reason"] == pilot.reason and s["precision_kind"] == "single"


def test_old_corrections_stop_it():
    pilot, t = following_on_fixed(min_solution="float", max_diff_age_s=5.0)
    t = drive(pilot, t, t + 3 * S, gnss_kind="fixed", gnss_diff_age_s=4.9)
    assert pilot.mode == "following"
    t = drive(pilot, t, t + 1100 * MS, gnss_kind="fixed", gnss_diff_age_s=7.2)
    assert pilot.mode == "stopped" and pilot.reason == "corrections 7.2 s old, limit 5 s"
    # and a start is refused until they are young again, for a second
    assert pilot.start(t) == "corrections 7.2 s old, limit 5 s"
    t = drive(pilot, t, t + 1100 * MS, gnss_kind="fixed", gnss_diff_age_s=1.0)
    assert pilot.start(t) is None


def test_corrections_of_unknown_age_are_not_young_unless_no_limit():
    rule = Precision(PrecisionSettings(min_solution="dgps"))
    assert rule.problem("dgps", None) == "corrections of unknown age, limit 5 s"
    rule = Precision(PrecisionSettings(min_solution="dgps", max_diff_age_s=0.0))
    assert rule.problem("dgps", None) is None and rule.problem("fixed", 100.0) is None
    assert rule.problem("single", None) == "solution single, the pilot needs dgps or better"
    assert rule.problem("none", None) == "no GNSS solution, the pilot needs dgps or better"
    assert rule.problem("something_new", None) == "solution something_new, the pilot needs dgps or better"
    # a single-point minimum asks for no corrections
    assert Precision(PrecisionSettings(min_solution="single")).problem("single", None) is None


def test_a_negative_or_nan_age_is_an_unknown_age():
    """Review of issue 28: corrections -100 s old are not young ones."""
    rule = Precision(PrecisionSettings(min_solution="float"))
    for age in (-100.0, -0.1, float("nan")):
        assert rule.problem("fixed", age) == "corrections of unknown age, limit 5 s"
    assert rule.problem("fixed", 0.0) is None
    pilot, t = following_on_fixed(min_solution="fixed")
    t = drive(pilot, t, t + 1100 * MS, gnss_kind="fixed", gnss_diff_age_s=-3.0)
    assert pilot.mode == "stopped" and pilot.reason == "corrections of unknown age, limit 5 s"


def test_solution_ranks():
    assert [solution_rank(k) for k in SOLUTION_KINDS] == list(range(len(SOLUTION_KINDS)))
    assert solution_rank("something_new") == solution_rank(None) == -1


def test_warn_keeps_following_and_says_so():
    pilot, t = following_on_fixed(min_solution="fixed", on_imprecise="warn")
    t = drive(pilot, t, t + 2 * S, gnss_kind="float", gnss_diff_age_s=2.0)
    assert pilot.mode == "following" and pilot.reason is None
    s = state(pilot, t)
    assert s["precision_ok"] is False and s["precision_reason"] == "solution float, the pilot needs fixed"
    view = monitor_view(s)
    assert isinstance(view["solution"], Alert)
    assert view["solution"] == "float, corrections 2.0 s old: solution float, the pilot needs fixed"
    # a start while imprecise is allowed too
    pilot.stop("stop command")
    assert pilot.start(t) is None


def test_an_estimator_that_does_not_say_its_solution():
    pilot = pilot_with(min_solution="float")
    t = drive(pilot, T0, T0 + 2 * S, gnss_kind=None)
    assert pilot.start(t) == ("the estimate does not say its GNSS solution (an older estimator?), "
                              "the pilot needs float or better")


def test_the_estimate_carries_the_solution():
    base = {"t": T0, "mode": "navigating", "position_valid": True, "heading_valid": True,
            "origin": [38.7, -9.1, 100.0], "enu_m": [1.0, 2.0, 0.0], "yaw_rad": 0.0, "speed_mps": 3.0,
            "sigma_h_m": 0.02, "lat_deg": 38.7, "lon_deg": -9.1}
    older = estimate_of(base)
    assert older.gnss_kind is None and older.gnss_diff_age_s is None
    newer = estimate_of(dict(base, gnss_kind="fixed", gnss_diff_age_s=1.5, gnss_kinds={"gnss0": "fixed"}))
    assert newer.gnss_kind == "fixed" and newer.gnss_diff_age_s == 1.5


def test_the_settings():
    s = from_mapping(PilotServiceSettings, {"min_solution": "float", "max_diff_age_s": 3, "on_imprecise": "warn",
                                            "precision_hold_s": 2.0}, "test")
    assert s.precision == PrecisionSettings("float", 3.0, "warn", 2.0)
    with pytest.raises(ConfigError, match="min_solution"):
        from_mapping(PilotServiceSettings, {"min_solution": "rtk"}, "test")
    with pytest.raises(ValueError, match="min_solution"):
        Pilot(PilotSettings(precision=PrecisionSettings(min_solution="rtk")))
    with pytest.raises(ValueError, match="precision_hold_s"):
        Precision(PrecisionSettings(precision_hold_s=-1.0))
