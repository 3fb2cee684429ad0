"""Bad, late and out-of-order input: rejected and counted, never fed to the filter, and the
state never carries a NaN."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from estimator_helpers import generate, settings_for
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.simdrive import Drive
from viena.common.samples.estimator import STATE
from viena.services.estimator.estimator import Estimator

DRIVE = Drive(duration_s=25.0, seed=11)


@pytest.fixture(scope="module")
def drive():
    samples, origin = generate(DRIVE)
    return [(k, s) for k, s, _ in samples], origin


def fresh(drive, until_s: float = 12.0, **extra):
    """An estimator fed the drive's first `until_s` seconds, and the rest of the drive."""
    samples, origin = drive
    est = Estimator(settings_for(DRIVE, origin, **extra))
    t_end = samples[0][1]["t"] + int(until_s * 1e9)
    rest = []
    for kind, s in samples:
        if s["t"] > t_end:
            rest.append((kind, s))
        else:
            (est.add_imu if kind == "imu" else est.add_gnss)(s)
    return est, rest


def first(rest, kind):
    return copy.deepcopy(next(s for k, s in rest if k == kind))


def add_fix(est, rest, fix):
    """A fix from the IMU's future waits for the IMU: feed the IMU past it."""
    est.add_gnss(fix)
    for kind, s in rest:
        if kind == "imu" and s["t"] <= fix["t"] + 20_000_000:
            est.add_imu(s)


BAD_IMU = [
    ("non_finite", lambda s: s["accel_mps2"].__setitem__(0, math.nan)),
    ("non_finite", lambda s: s["gyro_radps"].__setitem__(2, math.inf)),
    ("non_finite", lambda s: s.__setitem__("mag_T", [1e-5, -math.inf, 0.0])),
    ("accel_range", lambda s: s["accel_mps2"].__setitem__(2, 16.5 * 9.80665)),
    ("accel_range", lambda s: s["accel_mps2"].__setitem__(0, -200.0)),
    ("gyro_range", lambda s: s["gyro_radps"].__setitem__(1, 40.0)),
    ("mag_range", lambda s: s.__setitem__("mag_T", [0.5, 0.0, 0.0])),
    ("malformed", lambda s: s.pop("accel_mps2")),
    ("malformed", lambda s: s.__setitem__("gyro_radps", [0.0, 0.0])),
    ("malformed", lambda s: s.__setitem__("accel_mps2", ["1", 0.0, 9.8])),
    ("malformed", lambda s: s.__setitem__("t", 1.5e18)),
    ("future", lambda s: s.__setitem__("t", s["t"] + 2 * 3600 * 10**9)),
]

BAD_FIX = [
    ("sigma", lambda f: f.__setitem__("ecef_sigma_m", [1.0, 0.0, 1.0])),
    ("sigma", lambda f: f.__setitem__("ecef_sigma_m", [1.0, -2.0, 1.0])),
    ("sigma", lambda f: f.__setitem__("vel_sigma_mps", [0.0, 0.1, 0.1])),
    ("non_finite", lambda f: f["ecef_m"].__setitem__(1, math.nan)),
    ("non_finite", lambda f: f.__setitem__("vel_ecef_mps", [0.0, math.inf, 0.0])),
    ("position_range", lambda f: f.__setitem__("ecef_m", [1.0e3, 2.0e3, 3.0e3])),
    ("velocity_range", lambda f: f.__setitem__("vel_ecef_mps", [150.0, 0.0, 0.0])),
    ("malformed", lambda f: f.__setitem__("valid", "yes")),
    ("malformed", lambda f: f.pop("ecef_m")),
    ("future", lambda f: f.__setitem__("t", f["t"] + 2 * 3600 * 10**9)),
]


@pytest.mark.parametrize("reason, spoil", BAD_IMU, ids=[r for r, _ in BAD_IMU])
def test_bad_imu_samples_are_rejected_and_counted(drive, reason, spoil):
    est, rest = fresh(drive)
    before = est.state()
    sample = first(rest, "imu")
    spoil(sample)
    assert est.add_imu(sample) is False
    after = est.state()
    assert after["input_rejected"] == {reason: 1}
    assert after["counts"]["imu"] == before["counts"]["imu"]
    assert after["enu_m"] == before["enu_m"] and after["quat"] == before["quat"]


@pytest.mark.parametrize("reason, spoil", BAD_FIX, ids=[r for r, _ in BAD_FIX])
def test_bad_gnss_fixes_are_rejected_and_counted(drive, reason, spoil):
    est, rest = fresh(drive)
    before = est.state()
    fix = first(rest, "gnss")
    spoil(fix)
    assert est.add_gnss(fix) is False
    after = est.state()
    assert after["input_rejected"] == {reason: 1}
    assert after["gnss_used"] == before["gnss_used"] and after["enu_m"] == before["enu_m"]


def test_far_future_means_ahead_of_the_clock_when_there_is_one(drive):
    samples, origin = drive
    clock_ns = samples[0][1]["t"]
    est = Estimator(settings_for(DRIVE, origin), clock=lambda: clock_ns)
    kind, s = next((k, s) for k, s in samples if k == "imu" and s["t"] > clock_ns + 3 * 10**9)
    assert est.add_imu(s) is False and est.input_rejected == {"future": 1}
    assert est.add_imu(samples[0][1]) is True


def test_no_fix_and_unusable_solutions_are_refused_by_status(drive):
    est, rest = fresh(drive)
    fix = first(rest, "gnss")
    fix.update(valid=False, pos_status="INSUFFICIENT_OBS", ecef_m=[100.0, 0.0, 0.0],
               ecef_sigma_m=[0.0, 0.0, 0.0])
    used = est.gnss_used
    add_fix(est, rest, fix)
    assert est.gnss_rejected == {"status": 1} and est.gnss_used == used
    assert est.input_rejected == {}                        # well-formed: not bad input
    fix = first(rest, "gnss")
    fix["ecef_sigma_m"] = [80.0, 80.0, 80.0]
    est.add_gnss(fix)
    assert est.gnss_rejected == {"status": 1, "sigma": 1}


def test_a_wild_fix_fails_the_innovation_test(drive):
    est, rest = fresh(drive, until_s=20.0)
    fix = first(rest, "gnss")
    fix["ecef_m"] = [v + 40.0 for v in fix["ecef_m"]]
    used = est.gnss_used
    add_fix(est, rest, fix)
    assert est.gnss_rejected == {"innovation": 1} and est.gnss_used == used


def test_gnss_that_keeps_disagreeing_wins_after_half_of_gnss_reset_s_without_a_reset(drive):
    """A receiver that jumps 30 m and stays there: a burst of refusals is the receiver's,
    refusals for half of gnss_reset_s are the filter's own doubt (consistency.py): it widens
    its position block and follows GNSS, attitude and all kept, instead of resetting."""
    est, rest = fresh(drive, until_s=10.0, gnss_reset_s=2.0)
    shifted = []
    for kind, s in rest:
        if kind == "gnss":
            s = copy.deepcopy(s)
            s["ecef_m"] = [s["ecef_m"][0] + 30.0, *s["ecef_m"][1:]]
        shifted.append((kind, s))
    for kind, s in shifted:
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
    state = est.state()
    assert state["counts"]["resets"] == 0 and state["counts"]["inflations"] >= 1
    assert 10 <= state["gnss_rejected"]["innovation"] <= 14          # 1 s at 10 Hz
    fix = next(s for k, s in reversed(shifted) if k == "gnss")
    assert np.linalg.norm(np.array(est.frame.enu_of_ecef(fix["ecef_m"])) - state["enu_m"]) < 5.0


def test_gnss_that_disagrees_for_gnss_reset_s_before_any_widening_wins_by_a_reset(drive):
    """The reset stays the last resort: with gnss_reset_s shorter than the three refusals a
    widening waits for, position, velocity and attitude start again from GNSS."""
    est, rest = fresh(drive, until_s=10.0, gnss_reset_s=0.15)
    for kind, s in rest:
        if kind == "gnss":
            s = copy.deepcopy(s)
            s["ecef_m"] = [s["ecef_m"][0] + 30.0, *s["ecef_m"][1:]]
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
    state = est.state()
    assert state["counts"]["resets"] >= 1 and "GNSS disagreed" in state["last_reset"]


@pytest.mark.parametrize("rate, expected", [(10.0, 0.5), (0.0, 1.0), (20.0, 1.0)])
def test_fixes_are_used_at_most_at_gnss_max_rate_hz_per_receiver(drive, rate, expected):
    samples, origin = drive
    est = Estimator(settings_for(DRIVE, origin, gnss_max_rate_hz=rate,
                                 gnss_lever_arm_m={"gnss0": [0.0, 1.0, 1.5], "gnss1": [0.0, 1.0, 1.5]}))
    fixes = 0
    for kind, s in samples:
        if kind == "gnss":
            est.add_gnss(s)
            est.add_gnss(dict(s, unit="gnss1"))          # a second receiver, same epochs
            fixes += 2
        else:
            est.add_imu(s)
    state = est.state()
    assert state["gnss_used"] == pytest.approx(expected * fixes, abs=4)
    assert state["gnss_used"] + state["counts"]["gnss_decimated"] == fixes
    assert state["gnss_live"] == ["gnss0", "gnss1"]


def test_late_and_duplicate_imu_samples_are_dropped_and_counted(drive):
    est, rest = fresh(drive)
    imu = [s for k, s in rest if k == "imu"][:3]
    assert est.add_imu(imu[1]) and not est.add_imu(imu[0]) and not est.add_imu(imu[1])
    assert est.input_rejected == {"imu_late": 1, "imu_duplicate": 1}
    other = dict(imu[2], unit="imu1")
    assert not est.add_imu(other) and est.input_rejected["imu_other_unit"] == 1


def test_another_imu_takes_over_only_when_the_first_went_quiet(drive):
    est, rest = fresh(drive)
    imu = [s for k, s in rest if k == "imu"]
    assert est.add_imu(imu[0]) and not est.add_imu(dict(imu[1], unit="imu1"))
    later = [dict(s, unit="imu1") for s in imu[60:200]]        # imu0 silent for 0.7 s
    assert all(est.add_imu(s) for s in later)
    assert est.imu_unit == "imu1" and est.state()["aligned"]
    assert not est.add_imu(dict(imu[201], unit=0.0)) and est.input_rejected["malformed"] == 1


def test_late_gnss_is_used_at_its_own_time_and_too_late_is_dropped(drive):
    """Fixes arriving 0.3 s after the IMU samples of their epoch (the receiver's latency)
    give the same estimate as fixes in time order; fixes older than late_window_s are
    dropped and counted."""
    samples, origin = drive
    in_order = Estimator(settings_for(DRIVE, origin))
    delayed = Estimator(settings_for(DRIVE, origin))
    waiting = []
    for kind, s in samples:
        (in_order.add_imu if kind == "imu" else in_order.add_gnss)(s)
        if kind == "gnss":
            waiting.append(s)
            continue
        delayed.add_imu(s)
        while waiting and waiting[0]["t"] < s["t"] - 300_000_000:
            delayed.add_gnss(waiting.pop(0))
    a, b = in_order.state(), delayed.state()
    assert b["input_rejected"] == {} and b["gnss_used"] >= a["gnss_used"] - 8
    assert np.linalg.norm(np.subtract(a["enu_m"], b["enu_m"])) < 0.3
    assert np.linalg.norm(np.subtract(a["vel_enu_mps"], b["vel_enu_mps"])) < 0.1
    assert abs(math.remainder(a["yaw_rad"] - b["yaw_rad"], 2 * math.pi)) < math.radians(1.0)
    stale = dict(waiting[0] if waiting else samples[-1][1], t=b["t"] - 2 * 10**9)
    assert delayed.add_gnss(stale) is False and delayed.input_rejected == {"gnss_late": 1}


def test_one_bad_time_does_not_lock_the_filter_out(drive):
    """A first sample stamped 30 s ahead makes every real one look late; after 200 of them
    in a row the estimator takes the real timeline and starts again."""
    samples, origin = drive
    est = Estimator(settings_for(DRIVE, origin))
    est.add_imu(dict(samples[0][1], t=samples[0][1]["t"] + 30 * 10**9))
    for kind, s in samples[1:1500]:
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
    state = est.state()
    assert state["input_rejected"]["imu_late"] == 200
    assert state["counts"]["resets"] == 1 and "went back" in state["last_reset"]
    assert state["aligned"] and state["position_valid"] and state["mode"] == "navigating"


def test_a_fix_from_the_imus_future_waits_for_the_imu(drive):
    samples, origin = drive
    est = Estimator(settings_for(DRIVE, origin))
    imu = [s for k, s in samples if k == "imu"]
    fix = next(s for k, s in samples if k == "gnss" and s["t"] > imu[200]["t"])
    for s in imu[:200]:
        est.add_imu(s)
    assert est.add_gnss(fix) and not est.state()["position_valid"]        # waiting
    for s in imu[200:210]:
        est.add_imu(s)
    assert est.state()["position_valid"] and est.gnss_used == 1


def test_divergence_resets_says_why_and_realigns(drive):
    est, rest = fresh(drive, until_s=15.0)
    est.kf.P[0, 0] = 1e12                                   # a covariance blow-up
    for kind, s in rest[:200]:
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
    state = est.state()
    assert state["counts"]["resets"] == 1 and "diverged" in state["last_reset"]
    assert state["aligned"] and state["position_valid"]     # realigned and reinitialised
    STATE.encode(dict(state))


def test_a_nan_inside_the_filter_is_never_published(drive):
    est, _ = fresh(drive)
    est.kf.x[4] = math.nan
    state = est.state()
    assert state["counts"]["resets"] == 1 and "not finite" in state["last_reset"]
    STATE.encode(dict(state))


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20),
                    st.text(max_size=3), st.none(), st.booleans())
values = st.one_of(numbers, st.lists(numbers, max_size=4),
                   st.dictionaries(st.text(max_size=2), numbers, max_size=2))
FIELDS = ["t", "unit", "accel_mps2", "gyro_radps", "mag_T", "valid", "pos_status", "ecef_m",
          "ecef_sigma_m", "vel_ecef_mps", "vel_sigma_mps", "vel_status", "vel_latency_s"]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(spoils=st.lists(st.tuples(st.integers(0, 399), st.sampled_from(FIELDS), values), max_size=12))
def test_fuzzed_samples_never_break_the_filter_nor_make_a_nan(drive, spoils):
    samples, origin = drive
    head = samples[:400]                        # 3.8 s: aligning, initialising, driving off
    by_index = {}
    for i, field, value in spoils:
        by_index.setdefault(i, []).append((field, value))
    est = Estimator(settings_for(DRIVE, origin))
    for i, (kind, s) in enumerate(head):
        if i in by_index:
            s = copy.deepcopy(s)
            for field, value in by_index[i]:
                s[field] = value
        (est.add_imu if kind == "imu" else est.add_gnss)(s)
        if i % 50 == 0:
            STATE.encode(dict(est.state()))
    state = est.state()
    STATE.encode(dict(state))
    assert state["aligned"] and state["position_valid"]


#: the fields the README's "Estimator" section says are read: any source may send only these
README_IMU = ("t", "unit", "accel_mps2", "gyro_radps", "mag_T")
README_FIX = ("t", "unit", "valid", "pos_status", "ecef_m", "ecef_sigma_m", "vel_ecef_mps",
              "vel_sigma_mps", "vel_latency_s")


def test_samples_with_only_the_documented_fields_give_the_same_estimate(drive):
    samples, origin = drive
    full, bare = Estimator(settings_for(DRIVE, origin)), Estimator(settings_for(DRIVE, origin))
    for kind, s in samples:
        fields = README_IMU if kind == "imu" else README_FIX
        short = {k: tuple(v) if isinstance(v, list) else v for k, v in s.items() if k in fields}
        (full.add_imu if kind == "imu" else full.add_gnss)(s)
        assert (bare.add_imu if kind == "imu" else bare.add_gnss)(short)
    a, b = full.state(), bare.state()
    assert a["gnss_used"] > 100 and a["mode"] == "navigating"
    assert b == a
