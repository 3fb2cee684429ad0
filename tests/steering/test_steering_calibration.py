"""Calibration: the car's real power-up sweeps are accepted, the bogus one is refused, and
counts become angles by the laser fit."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from viena.services.steering.model.calibration import (
    Calibration,
    CalibrationRefused,
    CalibrationSettings,
    SweepRecorder,
    check_calibration,
    read_calibration_txt,
    zero_ref,
)

LOGS = Path(__file__).resolve().parents[3] / "shared/data/steering/encoder_logs"
needs_logs = pytest.mark.skipif(not LOGS.is_dir(), reason="shared/data/steering not present")

GOOD = ["Fri_Jun__8_19_49_36_2018", "Mon_Jun_11_15_22_47_2018", "Sat_Jun__9_13_21_00_2018"]
BOGUS = "Sat_Jun__9_13_56_18_2018"             # min 0, max 519: the sweep was never done


@needs_logs
@pytest.mark.parametrize("run", GOOD)
def test_the_cars_real_calibrations_are_accepted_and_cover_their_drives(run):
    lo, hi, zero = read_calibration_txt(LOGS / f"{run}.txt")
    cal = check_calibration(lo, hi, zero)
    assert cal.zero_qc == zero == zero_ref(lo, hi)
    log = np.loadtxt(LOGS / f"{run}.csv", delimiter=",", skiprows=1)
    assert lo <= log[:, 1].min() and log[:, 1].max() <= hi      # the run stayed inside the sweep
    assert cal.range_deg == (-29.0, 29.0)


@needs_logs
def test_the_bogus_calibration_is_refused():
    lo, hi, zero = read_calibration_txt(LOGS / f"{BOGUS}.txt")
    assert (lo, hi, zero) == (0, 519, 260)
    with pytest.raises(CalibrationRefused, match="span 519 qc .* not turned lock to lock"):
        check_calibration(lo, hi, zero)


@needs_logs
def test_the_bogus_runs_encoder_log_replayed_as_a_sweep_is_refused_too():
    """Feeding the recorder what the encoder said during that run: it never completes."""
    log = np.loadtxt(LOGS / f"{BOGUS}.csv", delimiter=",", skiprows=1)
    rec = SweepRecorder()
    for t, qc in log:
        rec.add(int(qc), t)
        assert not rec.done(t)
    with pytest.raises(CalibrationRefused, match="span 6 qc"):
        rec.result()


@pytest.mark.parametrize("lo, hi, zero, match", [
    (0, 519, 260, "span 519"),
    (-60_000, 60_000, 0, "more than lock to lock"),
    (1000, 1000, 1000, "span 0 qc"),
    (1000, -1000, 0, "below min"),
    (-47_752, 47_308, 5_000, "not the middle"),
    (-47_752.0, 47_308, -222, "integer"),
    (True, 47_308, -222, "integer"),
])
def test_impossible_numbers_are_refused_with_the_reason(lo, hi, zero, match):
    with pytest.raises(CalibrationRefused, match=match):
        check_calibration(lo, hi, zero)


def test_counts_become_the_laser_fit_angle_limited_to_29_degrees():
    cal = check_calibration(-47_752, 47_308, -222)
    assert cal.angle_deg(-222) == 0.0
    assert cal.angle_deg(-222 + 10_000) == pytest.approx(-7.5014)       # slope -7.5014e-4 deg/qc
    assert cal.measured_deg(-47_752) == 29.0 and cal.measured_deg(47_308) == -29.0
    assert cal.angle_deg(cal.qc_of(12.5)) == pytest.approx(12.5)
    lo, hi = cal.limits_qc()
    assert cal.angle_deg(lo) <= 29.0 and cal.angle_deg(hi) >= -29.0 and lo < -222 < hi


def test_slope_and_limit_are_settings():
    cal = check_calibration(-47_752, 47_308, None, CalibrationSettings(slope_deg_per_qc=5e-4, limit_deg=20.0))
    assert cal.angle_deg(-222 + 1000) == pytest.approx(0.5)
    assert cal.range_deg == (-20.0, 20.0)


def test_a_narrow_sweep_gives_a_narrow_range():
    cal = Calibration(-30_000, 30_000, 0)            # only +-22.5 deg reachable
    lo, hi = cal.range_deg
    assert lo == pytest.approx(-22.5042) and hi == pytest.approx(22.5042)


def sweep(recorder, points, t0=0.0, rate=100.0, speed=60_000.0):
    """Feed a piecewise-linear hand movement through `points`; returns the end time."""
    t = t0
    pos = points[0]
    for target in points[1:]:
        n = max(1, int(abs(target - pos) / speed * rate))
        for k in range(1, n + 1):
            t += 1 / rate
            recorder.add(round(pos + (target - pos) * k / n), t)
        pos = target
    return t


def test_a_sweep_completes_when_the_wheel_is_back_in_the_middle_and_still():
    rec = SweepRecorder()
    t = sweep(rec, [1500, 49_100, -46_100, 1500])
    assert not rec.done(t)                            # just arrived: not still yet
    for _ in range(60):
        t += 0.01
        rec.add(1500, t)
    assert rec.done(t)
    cal = rec.result()
    assert (cal.min_qc, cal.max_qc, cal.zero_qc) == (-46_100, 49_100, 1500)


def test_a_sweep_starts_from_the_first_reading_not_from_zero():
    """The old code's min/max started at 0, which made a wheel left of centre look swept."""
    rec = SweepRecorder()
    rec.add(40_000, 0.0)
    assert (rec.min_qc, rec.max_qc) == (40_000, 40_000)


def test_a_sweep_that_stops_at_one_lock_never_completes():
    rec = SweepRecorder()
    t = sweep(rec, [0, 47_000, 0])
    for _ in range(100):
        t += 0.01
        rec.add(0, t)
    assert not rec.done(t)
    with pytest.raises(CalibrationRefused):
        rec.result()


def test_glitches_and_impossible_spans_restart_the_sweep():
    rec = SweepRecorder()
    rec.add(0, 0.0)
    rec.add(30_000, 0.01)                             # no hand turns 30 000 qc in 10 ms
    assert "jumped" in rec.problem and (rec.min_qc, rec.max_qc) == (30_000, 30_000)
    rec = SweepRecorder()
    sweep(rec, [0, 60_000, -60_000])
    assert "more than lock to lock" in rec.problem and rec.span_qc < 100_000


def test_a_glitch_restarts_the_sweep_but_a_slow_reader_does_not():
    rec = SweepRecorder()
    rec.add(0, 0.00)
    rec.add(30_000, 0.01)                      # 3 000 000 qc/s: no hand, an encoder glitch
    assert rec.problem.startswith("counter jumped 0 -> 30000") and rec.samples == 1
    rec = SweepRecorder()
    rec.add(0, 0.00)
    rec.add(30_000, 0.50)                      # a busy host read half a second later
    assert rec.problem == "" and rec.span_qc == 30_000
