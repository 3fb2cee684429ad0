"""Our Madgwick against the `ahrs` package's on the same data, and on the car's recordings.

ahrs writes its Earth frame with the field on +x (north-west-up); ours is ENU with the
car's yaw 0 on north, so the same filter must give q_ours = Rz(90 deg) * q_ahrs.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from ahrs.filters import Madgwick as AhrsMadgwick
from estimator_recordings import IMU_PARKED, RAZOR_RATE_HZ, razor_parked_samples

from viena.common.rotation import euler_from_quat, quat_from_euler, quat_multiply, quat_to_matrix
from viena.services.estimator.madgwick import Madgwick

Q_NWU_TO_ENU = quat_from_euler(math.pi / 2, 0.0, 0.0)
LISBON_T = np.array([-1121.5, 26479.8, -34884.7]) * 1e-9


def tumbling(n: int, dt: float, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """gyro, accel, mag of a sensor turning about every axis, with noise."""
    q = quat_from_euler(0.4, 0.3, -0.2)
    gyro, acc, mag = [], [], []
    for k in range(n):
        w = np.array([0.6 * math.sin(0.7 * k * dt), 0.5 * math.cos(0.45 * k * dt), 0.8])
        half = 0.5 * w * dt
        q = quat_multiply(q, [1.0, *half])
        q = q / np.linalg.norm(q)
        r = quat_to_matrix(q)
        gyro.append(w + rng.normal(0, 0.01, 3))
        acc.append(r.T @ [0, 0, 9.81] + rng.normal(0, 0.2, 3))
        mag.append(r.T @ LISBON_T + rng.normal(0, 0.5e-6, 3))
    return np.array(gyro), np.array(acc), np.array(mag)


@pytest.mark.parametrize("marg", [True, False])
def test_same_quaternions_as_ahrs_on_a_tumbling_sensor(marg):
    rng = np.random.default_rng(3)
    dt, beta = 1 / 82.5, 0.1
    gyro, acc, mag = tumbling(1500, dt, rng)
    ref = AhrsMadgwick(gain=beta, Dt=dt)
    ours = Madgwick(beta=beta)
    q_ref = np.array(quat_from_euler(0.1, 0.0, 0.0))
    ours.set_quaternion(quat_multiply(Q_NWU_TO_ENU, q_ref))
    worst = 0.0
    for g, a, m in zip(gyro, acc, mag):
        if marg:
            q_ref = ref.updateMARG(q_ref, g, a, m, dt=dt)
            ours.update_marg(*g, *a, *m, dt)
        else:
            q_ref = ref.updateIMU(q_ref, g, a, dt=dt)
            ours.update_imu(*g, *a, dt)
        expected = quat_multiply(Q_NWU_TO_ENU, q_ref)
        worst = max(worst, min(np.abs(np.array(ours.q) - expected).max(),
                               np.abs(np.array(ours.q) + expected).max()))
    assert worst < 1e-9


def test_same_quaternions_as_ahrs_on_the_parked_car():
    """The real Razor recording (IMU-only: its magnetometer is uncalibrated here)."""
    samples = razor_parked_samples(IMU_PARKED[0])
    dt = 1 / RAZOR_RATE_HZ
    ref = AhrsMadgwick(gain=0.05, Dt=dt)
    ours = Madgwick(beta=0.05)
    q_ref = np.array([1.0, 0.0, 0.0, 0.0])
    ours.set_quaternion(Q_NWU_TO_ENU)
    checked = 0
    for s in samples:
        g, a = s["gyro_radps"], s["accel_mps2"]
        if not any(g):
            continue                # ahrs skips the whole step when the gyro reads exactly zero
        q_ref = ref.updateIMU(q_ref, np.array(g), np.array(a), dt=dt)
        ours.update_imu(*g, *a, dt)
        np.testing.assert_allclose(ours.q, quat_multiply(Q_NWU_TO_ENU, q_ref), atol=1e-9)
        checked += 1
    assert checked > 1000


def test_the_declination_turns_the_filter_onto_true_north():
    """With the Lisbon field (declination -2.43 deg) a still car facing true north reads
    yaw 0, and the filter converges there from 30 deg off."""
    declination = math.atan2(LISBON_T[0], LISBON_T[1])
    for yaw_true in (0.0, 1.0, -2.5):
        r = quat_to_matrix(quat_from_euler(yaw_true, 0.02, -0.03))
        m = Madgwick(beta=0.2, declination_rad=declination, q=quat_from_euler(yaw_true + 0.5, 0, 0))
        for k in range(3000):
            m.beta = 0.2 if k < 2000 else 0.01         # converge, then stop chattering
            m.update_marg(0.0, 0.0, 0.0, *(r.T @ [0, 0, 9.8]), *(r.T @ LISBON_T), 0.01)
        yaw, pitch, roll = euler_from_quat(m.q)
        assert math.degrees(abs(math.remainder(yaw - yaw_true, 2 * math.pi))) < 0.05
        assert (pitch, roll) == pytest.approx((0.02, -0.03), abs=1e-3)


def test_turning_about_the_world_up_axis_changes_yaw_only():
    m = Madgwick(declination_rad=0.1, q=quat_from_euler(0.3, 0.1, -0.2))
    m.rotate_world_z(0.5)
    yaw, pitch, roll = euler_from_quat(m.q)
    assert (yaw, pitch, roll) == pytest.approx((0.8, 0.1, -0.2), abs=1e-12)


def test_a_quaternion_without_direction_is_refused():
    with pytest.raises(ValueError):
        Madgwick(q=(0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError):
        Madgwick().set_quaternion((float("nan"), 0.0, 0.0, 1.0))
