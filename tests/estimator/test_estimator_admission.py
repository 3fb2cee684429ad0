"""A receiver is used only after its fixes pass the quality checks for admit_hold_s, and
put back on probation when they fail that long (services/estimator/admission.py)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from estimator_helpers import generate, settings_for

from benchmarks.simdrive import Drive
from viena.services.estimator.estimator import Estimator

DRIVE = Drive(duration_s=40.0, seed=5, with_mag=False)


@pytest.fixture(scope="module")
def drive():
    samples, origin = generate(DRIVE)
    return [(k, s) for k, s, _ in samples], origin


def feed(est, samples, change=None):
    """Feed the drive; `change(fix, t_s)` may alter each fix (a copy) first. Returns the
    last state and when (s into the drive) a fix was first used."""
    t0 = samples[0][1]["t"]
    first_used = None
    for kind, s in samples:
        if kind == "imu":
            est.add_imu(s)
        else:
            if change is not None:
                s = change(copy.deepcopy(s), (s["t"] - t0) * 1e-9)
            est.add_gnss(s)
        if first_used is None and est.gnss_used:         # a fix waits for the IMU to pass it
            first_used = (s["t"] - t0) * 1e-9
    return est.state(), first_used


def test_a_receiver_is_used_after_its_fixes_passed_for_the_hold(drive):
    samples, origin = drive
    settings = settings_for(DRIVE, origin)
    del settings["admit_hold_s"]                        # the default: PX4's 10 s
    state, first_used = feed(Estimator(settings), samples)
    assert 10.0 <= first_used < 10.5
    assert state["gnss_admission"] == {"gnss0": "in use"}
    # 10 s of fixes at the estimator's 10 Hz were on probation (the rest decimated)
    assert 95 <= state["gnss_rejected"]["probation"] <= 105
    assert state["position_valid"] and state["counts"]["resets"] == 0


def test_too_few_satellites_or_too_large_a_sigma_keep_a_receiver_out(drive):
    samples, origin = drive

    def few_sats(fix, t_s):
        fix["sats_used"] = 4
        return fix

    state, first_used = feed(Estimator(settings_for(DRIVE, origin, admit_hold_s=5.0)), samples, few_sats)
    assert first_used is None and not state["position_valid"]
    assert state["gnss_admission"] == {"gnss0": "failing sats"}
    assert state["gnss_rejected"]["quality_sats"] > 300

    def wide(fix, t_s):
        fix["ecef_sigma_m"] = [12.0, 12.0, 12.0]
        return fix

    state, first_used = feed(Estimator(settings_for(DRIVE, origin, admit_hold_s=5.0)), samples, wide)
    assert first_used is None and "quality_sigma_h" in state["gnss_rejected"]


def test_a_receiver_failing_for_the_hold_goes_back_on_probation(drive):
    samples, origin = drive

    def bad_from_20_s(fix, t_s):
        if 20.0 <= t_s < 32.0:
            fix["sats_used"] = 3
        return fix

    est = Estimator(settings_for(DRIVE, origin, admit_hold_s=5.0))
    state, first_used = feed(est, samples, bad_from_20_s)
    assert 5.0 <= first_used < 5.5
    rejected = state["gnss_rejected"]
    # 12 s failing (5 s of it while still in use, then on probation), then 5 s of probation again
    assert 110 <= rejected["quality_sats"] <= 125
    assert 95 <= rejected["probation"] <= 110            # the first 5 s, and 5 s after 32 s
    assert state["gnss_admission"] == {"gnss0": "in use"}


def test_fixes_drifting_while_the_car_stands_are_not_admitted(drive):
    samples, origin = drive

    east = np.array([-math.sin(math.radians(origin[1])), math.cos(math.radians(origin[1])), 0.0])

    def drifting(fix, t_s):
        # the receiver's position walks east at 3 m/s while the car stands (the first 10 s)
        fix["ecef_m"] = list(np.add(fix["ecef_m"], east * 3.0 * min(t_s, 10.0)))
        return fix

    settings = settings_for(DRIVE, origin)
    del settings["admit_hold_s"]                        # the default 10 s: the drift shows in it
    est = Estimator(settings)
    state, first_used = feed(est, samples, drifting)
    assert est.gnss_rejected.get("quality_drift", 0) >= 10
    # admitted only after 10 s of good fixes once the car drove off (the drift is judged standing)
    assert first_used is not None and first_used > 18.0
