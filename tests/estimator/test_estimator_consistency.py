"""The filter judges its sources and itself (issue 25): how the IMU sits in the car
(mount.py), the process noise it deserves and the widening after refusals in a row
(consistency.py), and what the state says of it."""
from __future__ import annotations

import math

import pytest
from estimator_helpers import generate, run, settings_for

from benchmarks.simdrive import at_speed
from viena.common.samples.estimator import STATE
from viena.services.estimator.consistency import Consistency
from viena.services.estimator.mount import MountHint

pytestmark = pytest.mark.slow        # 90 s simulated drives through the filter

#: the board turned 4 deg about the car's right axis (Mount zyx: yaw z, roll y, pitch x)
PITCHED = (0.0, 0.0, 4.0)


@pytest.fixture(scope="module")
def pitched():
    drive = at_speed(10.0, duration_s=90.0, seed=3, imu_mount_zyx_deg=PITCHED, with_mag=False)
    samples, origin = generate(drive)
    return drive, samples, origin


def test_an_imu_pitched_in_the_car_is_reported_with_the_mount_it_implies(pitched):
    drive, samples, origin = pitched
    r = run(samples, settings_for(drive, origin), check_schema=True)
    yaw, pitch = r.final["imu_mount_hint_deg"]
    # the car's forward axis seen from the board: pitched the other way
    assert pitch == pytest.approx(-4.0, abs=0.5) and yaw == 0.0
    assert r.final["counts"]["resets"] == 0
    assert r.final["gnss_rejected"].get("velocity_innovation", 0) <= 3
    assert r.rms(r.vel_err[:, :2]) < 0.15


def test_without_the_mount_hint_the_constraint_fights_gnss():
    """A board 6 deg pitched at 14 m/s, with the constraint along the board's own axes (the
    mount taken as calibrated: imu_mount_sigma_deg 0) and along the car's as the hint finds
    them: the constraint's 1.5 m/s of "vertical" velocity against GNSS's, or none."""
    drive = at_speed(14.0, duration_s=90.0, seed=3, imu_mount_zyx_deg=(0.0, 0.0, 6.0), with_mag=False)
    samples, origin = generate(drive)
    hinted = run(samples, settings_for(drive, origin))
    blind = run(samples, settings_for(drive, origin, imu_mount_sigma_deg=0.0))
    assert blind.final["imu_mount_hint_deg"] is None
    assert hinted.rms(hinted.vel_err[:, 2]) < 0.5 * blind.rms(blind.vel_err[:, 2])
    refused = lambda r: r.final["gnss_rejected"].get("velocity_innovation", 0)    # noqa: E731
    assert refused(hinted) <= 3 and hinted.final["counts"]["resets"] == 0
    assert refused(blind) > 10 or blind.final["counts"]["resets"] > 0


def test_a_filter_too_sure_of_its_imu_scales_its_process_noise_up_and_never_resets():
    """An accelerometer bias of 0.3 m/s^2 that the settings say cannot be there (bias sigma
    1 mm/s^2, no walk): the velocity keeps disagreeing, the process noise grows instead."""
    drive = at_speed(10.0, duration_s=90.0, seed=4, with_mag=False, accel_bias_mps2=(0.3, -0.3, 0.1))
    samples, origin = generate(drive)
    sure_of_no_bias = {"accel_bias_sigma_mps2": (0.001, 0.001, 0.001), "accel_bias_walk_psd": 1e-12,
                       "accel_psd": 5e-5}
    sure = run(samples, settings_for(drive, origin, **sure_of_no_bias)).final
    assert sure["process_noise_scale"] >= 8.0
    assert sure["counts"]["resets"] == 0
    assert set(sure["nis"]) == {"position", "velocity", "course", "heading"}
    assert all(0.0 <= v for v in sure["test_ratio"].values() if v is not None)
    # the same drive with the settings' own figures leaves the process noise as it is
    honest = run(samples, settings_for(drive, origin)).final
    assert honest["process_noise_scale"] <= 2.0


def test_refusals_in_a_row_widen_only_after_half_the_reset_time():
    judge = Consistency(inflate_after_s=2.5)
    t = 0
    for _ in range(9):                   # 9 refusals over 2 s at 4 Hz: the receiver's doing
        assert not judge.refused("gnss0", "position", False, t)
        t += 250_000_000
    assert not judge.refused("gnss0", "position", False, t)          # 2.25 s
    t += 250_000_000
    assert judge.refused("gnss0", "position", False, t)              # 2.5 s: ours
    assert not judge.refused("gnss0", "position", True, t)           # and counted afresh
    assert not judge.refused("gnss0", "position", False, t + 3_000_000_000)


def test_the_mount_hint_learns_only_from_straight_driving_at_speed():
    hint = MountHint(prior_sigma_deg=3.0)
    level = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    climb = math.radians(2.0)
    v = (0.0, 10.0 * math.cos(climb), 10.0 * math.sin(climb))       # along a 2 deg climb
    hint.observe(level, (0.0, 2.0, 0.0), 0.0, True)                  # too slow
    hint.observe(level, v, 0.3, True)                                # turning
    assert hint.hint_deg() is None and hint.var == pytest.approx(math.radians(3.0) ** 2)
    for _ in range(100):
        hint.observe(level, v, 0.0, True)
    assert hint.hint_deg() == pytest.approx([0.0, 2.0])
    assert math.sqrt(hint.var) < math.radians(0.2)


def test_the_new_state_fields_are_in_the_schema():
    fields = STATE.fields
    for name in ("imu_mount_hint_deg", "nis", "test_ratio", "process_noise_scale", "gnss_admission"):
        assert name in fields
