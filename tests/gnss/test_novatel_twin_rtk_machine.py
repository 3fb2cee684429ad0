"""The NovAtel twin's solution types (simulator/rtk.py) on the machine's own clock: the
progression the OEM4 manuals describe (PSRDIFF at once, float after three base
observations, fixed after a convergence growing with the baseline), the timeouts (RTK 60 s,
DGPSTIMEOUT), RT-2 against RT-20 and a DGPS-only model, outages and wrong fixes."""
from __future__ import annotations

import numpy as np
import pytest

from viena.services.gnss.driver.novatel import DgpsType, PositionType
from viena.services.gnss.simulator.rtk import (
    DGPS,
    RT2,
    RT20,
    RtkFigures,
    RtkMachine,
    Source,
    engine_of_model,
)

BASE = "7"
#: one fix attempt takes exactly its mean (no spread), and no fix is wrong
EXACT = RtkFigures(fix_spread=0.0, wrong_fix_chance=0.0, wrong_fix_chance_per_km=0.0)


def drive(machine: RtkMachine, seconds: float, *, baseline_m: float = 1000.0, start_s: float = 0.0,
          until_s: float | None = None, l2: bool = True, latency_s: float = 0.3, step_s: float = 1.0,
          outages=()) -> list:
    """Observables every second from `start_s` (read `latency_s` after their epoch, until
    `until_s`), asking the machine every `step_s`: [(t, status)]."""
    machine.base_position(start_s, BASE)
    out = []
    k = 0
    t = start_s
    while t < start_s + seconds:
        epoch = start_s + k
        while epoch + latency_s <= t + 1e-9:
            if until_s is None or epoch < until_s:
                machine.observe(epoch + latency_s, epoch, BASE, l2)
            k += 1
            epoch = start_s + k
        outage = any(a <= t < b for a, b in outages)
        out.append((t, machine.at(t, outage=outage, baseline_m=baseline_m)))
        t = round(t + step_s, 6)
    return out


def first(statuses, phase: str) -> float | None:
    return next((t for t, s in statuses if s.phase == phase), None)


def test_no_corrections_is_single():
    m = RtkMachine(RT2)
    assert {s.phase for _, s in drive(m, 30, until_s=-1)} == {"single"}
    assert m.at(31.0).pos_type is None and m.at(32.0).diff_age_s == 0.0


def test_dgps_at_once_then_float_after_three_observations_then_fixed():
    m = RtkMachine(RT2, figures=EXACT)
    s = drive(m, 60, baseline_m=1000.0, step_s=0.5)
    assert s[0][1].phase == "single"                      # t=0: nothing read yet (epoch 0 read at 0.3)
    assert s[1][1].pos_type == PositionType.PSRDIFF       # t=0.5: the first observables, at once
    assert first(s, "float") == 2.5                       # the third observation, read at 2.3
    assert [st.pos_type for t, st in s if t == 2.5] == [PositionType.NARROW_FLOAT]
    # the fix: the attempt's mean (20 s + 9 s/km) after the float started
    assert first(s, "fixed") == pytest.approx(2.5 + 29.0, abs=0.51)
    fixed = [st for _, st in s if st.phase == "fixed"]
    assert {st.pos_type for st in fixed} == {PositionType.NARROW_INT}
    assert all(st.base_id == BASE and 0.2 <= st.diff_age_s <= 1.2 for st in fixed)


def test_diff_age_is_the_time_since_the_base_epoch_in_use():
    m = RtkMachine(RT2, figures=EXACT)
    s = dict(drive(m, 10, step_s=0.25, latency_s=0.4))
    assert s[5.25].diff_age_s == pytest.approx(1.25)       # epoch 5 is read at 5.4: epoch 4 in use
    assert s[5.5].diff_age_s == pytest.approx(0.5)


def mean_time_to_fix(baseline_m: float, seeds=range(40)) -> float:
    times = []
    for seed in seeds:
        m = RtkMachine(RT2, seed=seed, figures=RtkFigures(wrong_fix_chance=0.0, wrong_fix_chance_per_km=0.0))
        s = drive(m, 1500, baseline_m=baseline_m, step_s=1.0)
        times.append(first(s, "fixed") - first(s, "float"))
    return float(np.mean(times))


def test_the_time_to_fix_grows_with_the_baseline():
    at_1, at_20 = mean_time_to_fix(1000.0), mean_time_to_fix(20_000.0)
    assert 15 <= at_1 <= 50                     # tens of seconds at 1 km
    assert 120 <= at_20 <= 320                  # minutes at 20 km


@pytest.mark.parametrize("baseline_km", [50, 100])
def test_a_base_too_far_away_never_fixes(baseline_km):
    m = RtkMachine(RT2, seed=1)
    s = drive(m, 3600, baseline_m=baseline_km * 1000.0, step_s=5.0)
    assert "fixed" not in {st.phase for _, st in s}
    assert s[-1][1].pos_type == PositionType.NARROW_FLOAT and m.fixes == 0


def test_rt20_and_l1_only_observables_float_on_l1_for_good():
    """RT-20 "will always use floating L1 ambiguities" (vol. 1 §6.5.1); L1-only corrections
    give an RT-2 receiver RT-20's solution (vol. 1 Table 13)."""
    for machine, l2 in ((RtkMachine(RT20, figures=EXACT), True), (RtkMachine(RT2, figures=EXACT), False)):
        s = drive(machine, 600, baseline_m=100.0, l2=l2, step_s=2.0)
        assert {st.pos_type for _, st in s} == {None, PositionType.PSRDIFF, PositionType.L1_FLOAT}


def test_a_dgps_only_model_never_goes_past_psrdiff():
    m = RtkMachine(engine_of_model("3151R"), figures=EXACT)
    assert m.engine == DGPS
    s = drive(m, 300, step_s=2.0)
    assert {st.pos_type for _, st in s} == {None, PositionType.PSRDIFF}


def test_engines_by_model_name():
    assert [engine_of_model(n) for n in ("RT2WA", "RT2W", "rt20", "RT20W", "3151R", "L1L2W")] == [
        RT2, RT2, RT20, RT20, DGPS, DGPS]


def test_when_corrections_stop_fixed_then_float_then_psrdiff_then_single():
    """RTK goes on from extrapolated observations (ambiguities kept for 30 s, the RTK
    timeout 60 s), then the pseudorange corrections until DGPSTIMEOUT (300 s), then SINGLE."""
    m = RtkMachine(RT2, figures=EXACT)
    s = dict(drive(m, 500, until_s=100.0, step_s=1.0))
    last_epoch = 99.0
    assert s[100.0].phase == "fixed"
    assert s[last_epoch + 30.0].phase == "fixed" and s[last_epoch + 31.0].phase == "float"
    assert s[last_epoch + 60.0].pos_type == PositionType.NARROW_FLOAT
    assert s[last_epoch + 61.0].pos_type == PositionType.PSRDIFF
    assert s[last_epoch + 300.0].pos_type == PositionType.PSRDIFF
    assert s[last_epoch + 300.0].diff_age_s == pytest.approx(300.0)
    after = s[last_epoch + 301.0]
    assert after.phase == "single" and after.diff_age_s == 0.0 and after.base_id == ""


def test_dgpstimeout_shorter_than_the_rtk_timeout():
    m = RtkMachine(RT2, figures=EXACT, dgps_timeout_s=20.0)
    s = dict(drive(m, 200, until_s=100.0))
    assert s[99.0 + 60.0].phase == "float"              # RTK's own 60 s, whatever DGPSTIMEOUT says
    assert s[99.0 + 61.0].phase == "single"


def test_corrections_back_after_the_rtk_timeout_start_over():
    m = RtkMachine(RT2, figures=EXACT)
    drive(m, 100)
    assert m.at(180.0).phase == "dgps"                  # 81 s without: the RTK filter was reset
    s = drive(m, 60, start_s=180.0)
    assert s[1][1].phase == "dgps" and first(s, "float") == 183.0      # three new observations
    assert first(s, "fixed") == pytest.approx(183.0 + 29.0, abs=1.0)   # a whole attempt, not a warm one


def test_an_outage_loses_the_fix_and_it_comes_back_sooner():
    m = RtkMachine(RT2, figures=EXACT)
    s = dict(drive(m, 120, outages=[(60.0, 62.0)], step_s=1.0))
    assert s[59.0].phase == "fixed"
    assert s[60.0].phase == s[61.0].phase == "none" and s[60.0].pos_type == PositionType.NONE
    assert s[62.0].phase == "float"
    refix = next(t for t in sorted(s) if t > 62.0 and s[t].phase == "fixed")
    assert refix - 62.0 == pytest.approx(0.3 * 29.0, abs=1.01)     # refix_factor x the mean
    assert s[62.0].convergence_s >= 50.0                # the float kept its convergence


def test_a_wrong_fix_is_decimetres_off_until_the_receiver_notices():
    figures = RtkFigures(fix_spread=0.0, wrong_fix_chance=1.0)
    m = RtkMachine(RT2, seed=4, figures=figures)
    s = drive(m, 200, step_s=1.0)
    fixed = [(t, st) for t, st in s if st.phase == "fixed"]
    assert fixed and fixed[0][1].wrong_offset_enu_m is not None
    east, north, _ = fixed[0][1].wrong_offset_enu_m
    assert 0.2 <= np.hypot(east, north) <= 0.6
    lasted = [t for t, st in fixed if st.wrong_offset_enu_m == fixed[0][1].wrong_offset_enu_m]
    assert 15.0 <= lasted[-1] - lasted[0] + 1.0 <= 61.0
    after = dict(s)[lasted[-1] + 1.0]
    assert after.phase == "float" and m.wrong_fixes >= 1


def test_sources_choose_the_base():
    m = RtkMachine(RT2, figures=EXACT)
    m.rtk_source = Source(DgpsType.RTCMV3, "8")          # RTK from base 8 only
    s = drive(m, 100)
    assert {st.phase for _, st in s} == {"single", "dgps"}  # base 7's corrections: pseudorange only
    m = RtkMachine(RT2, figures=EXACT)
    m.rtk_source = m.psr_source = Source(DgpsType.NONE)
    assert {st.phase for _, st in drive(m, 30)} == {"single"}
    assert Source(DgpsType.RTCMV3, "0007").accepts("7") and Source(DgpsType.RTCMV3, "ANY").accepts("12")


def test_observables_without_the_base_position_are_not_used_and_a_drop_is_at_once():
    m = RtkMachine(RT2, figures=EXACT)
    for k in range(10):
        m.observe(k + 0.3, float(k), BASE, True)
        assert m.at(k + 0.5).phase == "single"           # no 1005/1006 yet
    m.base_position(10.1, BASE)
    m.observe(10.3, 10.0, BASE, True)
    assert m.at(10.5).phase == "dgps"
    m.drop_corrections(10.6)
    assert m.at(10.7).phase == "single"


def test_another_base_starts_the_rtk_filter_again():
    m = RtkMachine(RT2, figures=EXACT)
    drive(m, 60)
    assert m.at(60.0).phase == "fixed"
    m.base_position(60.1, "9")
    m.observe(60.3, 60.0, "9", True)
    assert m.at(60.5).phase == "dgps" and m.at(60.5).base_id == "9"


def test_the_same_seed_and_events_give_the_same_solution():
    runs = [[(t, st.phase, st.wrong_offset_enu_m) for t, st in drive(RtkMachine(RT2, seed=9), 400, outages=[(100, 101)])]
            for _ in range(2)]
    assert runs[0] == runs[1]
