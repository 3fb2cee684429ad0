"""An IMU whose stamps are off the GNSS clock (issue 13, item 4).

A USB adapter or a busy Pi can stamp the IMU's samples hundreds of milliseconds late (or,
with a wrong correction, early). Before issue 13: 200 ms off and the heading was never
found again. Now: the heading stays within 3 deg RMS at 200 ms and 10 deg at 500 ms after
a minute of driving, no reset loop, and the state (and the service's health) says which
time offset the fixes point at, in the IMU service's own convention (time_offset_s:
t_true = t_stamped + offset).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from estimator_helpers import settings_for

from benchmarks.simdrive import Drive, DriveSamples
from viena.common.rotation import wrap_angle
from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.timing import OffsetHint


def drive_with_late_imu(late_s: float, seed: int = 1, duration_s: float = 130.0):
    """The campus loop without a magnetometer (yaw from the course), stamps `late_s` late.
    Returns the yaw error against the truth at the IMU sample's own moment after 60 s of
    driving, and the last state."""
    drive = Drive(duration_s=duration_s, seed=seed, imu_stamps_late_s=late_s, with_mag=False)
    samples = DriveSamples(drive)
    est = Estimator(settings_for(drive, samples.origin))
    yaw_err = []
    for kind, sample, truth in samples:
        if kind == "gnss":
            est.add_gnss(sample)
            continue
        est.add_imu(sample)
        if truth.t_s > 70.0:
            s = est.state()
            assert s["heading_valid"]
            yaw_err.append(wrap_angle(s["yaw_rad"] - yaw_pitch_roll(truth.quat)[0]))
    return math.degrees(math.sqrt(np.mean(np.square(yaw_err)))), est.state()


@pytest.mark.slow
@pytest.mark.parametrize("late_s, limit_deg", [(0.2, 3.0), (-0.2, 3.0), (0.5, 10.0), (-0.5, 10.0)])
def test_heading_survives_an_imu_clock_off_by_up_to_half_a_second(late_s, limit_deg):
    rms_deg, state = drive_with_late_imu(late_s)
    assert rms_deg < limit_deg
    assert state["counts"]["resets"] <= 1 and state["mode"] == "navigating"
    # the fixes point at the offset that would put it right
    assert state["imu_time_offset_hint_s"] == pytest.approx(-late_s, abs=0.05)


@pytest.mark.slow
def test_a_right_clock_gets_no_hint():
    rms_deg, state = drive_with_late_imu(0.0, duration_s=100.0)
    assert rms_deg < 1.0 and state["imu_time_offset_hint_s"] is None


def test_the_offset_hint_finds_the_lag_between_course_and_gyro():
    """The car drives a slalom: yaw rate 0.4 sin(2 pi t / 6). The gyro's samples are stamped
    0.3 s late; the fixes' courses (10 Hz, 0.5 deg of noise) are on time."""
    rng = np.random.default_rng(2)
    hint = OffsetHint()
    dt, late, speed = 0.01, 0.3, 5.0
    fixes = []
    for k in range(6000):                       # 60 s
        t = k * dt
        rate = 0.4 * math.sin(2 * math.pi * t / 6.0)
        # the gyro saw at stamp t + late what the car did at t
        hint.gyro(int((t + late) * 1e9), rate, dt)
        if k % 10 == 0:
            yaw = -0.4 * 6.0 / (2 * math.pi) * math.cos(2 * math.pi * t / 6.0) + rng.normal(0, 0.009)
            fixes.append((int(t * 1e9), -speed * math.sin(yaw), speed * math.cos(yaw)))
        # a fix arrives about when the gyro's samples of its time do
        while fixes and fixes[0][0] <= (t + late - 0.05) * 1e9:
            tf, ve, vn = fixes.pop(0)
            hint.course(tf, ve, vn, 0.03 ** 2)
    assert hint.late_s == pytest.approx(late, abs=0.02)
    assert hint.offset_s == pytest.approx(-late, abs=0.02)
    # a straight drive says nothing about time: no hint
    quiet = OffsetHint()
    for k in range(3000):
        quiet.gyro(k * 10_000_000, 0.0, dt)
        if k % 10 == 0:
            quiet.course(k * 10_000_000, 0.0, speed + rng.normal(0, 0.03), 0.03 ** 2)
    assert quiet.offset_s is None
