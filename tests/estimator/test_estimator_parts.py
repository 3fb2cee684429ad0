"""The estimator's small parts on their own: the Kalman filter's algebra, the trajectory
history that late fixes are compared with, the course-over-ground heading filter."""
from __future__ import annotations

import math

import numpy as np
import pytest

from viena.services.estimator.heading import UNKNOWN_VAR, HeadingFilter
from viena.services.estimator.history import TrajectoryHistory
from viena.services.estimator.kalman import Diverged, NavKalman
from viena.services.estimator.kalman_update import inverse_small


def test_inverse_small_matches_numpy_and_refuses_what_is_not_a_covariance():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3):
        a = rng.normal(size=(n, n))
        s = a @ a.T + np.eye(n)
        np.testing.assert_allclose(inverse_small(s), np.linalg.inv(s), rtol=1e-10, atol=1e-12)
    for bad in (np.zeros((3, 3)), -np.eye(2), np.full((1, 1), np.nan)):
        with pytest.raises(Diverged):
            inverse_small(bad)


def test_kalman_update_is_the_textbook_one():
    kf = NavKalman()
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, 6))
    kf.initialize([1.0, 2.0, 3.0], np.eye(3) * 4.0, [0.5, 0.0, 0.0], np.eye(3))
    kf.P[:6, :6] += 0.1 * (a @ a.T)
    P0, x0 = kf.P.copy(), np.array(kf.x)
    R = np.diag([1.0, 2.0, 3.0])
    nu = np.array([0.3, -0.2, 0.5])
    ok, d2, dx = kf.update_states(0, nu, R)
    H = np.zeros((3, 9))
    H[:, :3] = np.eye(3)
    S = H @ P0 @ H.T + R
    K = P0 @ H.T @ np.linalg.inv(S)
    assert ok and d2 == pytest.approx(nu @ np.linalg.inv(S) @ nu)
    np.testing.assert_allclose(kf.x, x0 + K @ nu, atol=1e-12)
    np.testing.assert_allclose(kf.P, (np.eye(9) - K @ H) @ P0, atol=1e-12)


def test_kalman_fix_update_equals_two_sequential_updates():
    """Position and velocity errors are independent: one stacked update is two in turn."""
    a, b = NavKalman(), NavKalman()
    rng = np.random.default_rng(2)
    m = rng.normal(size=(9, 9))
    for kf in (a, b):
        kf.initialize([0.0, 0.0, 0.0], np.eye(3), [1.0, 0.0, 0.0], np.eye(3) * 0.5)
        kf.P = kf.P + 0.05 * (m @ m.T)
    Rp, Rv = np.eye(3) * 2.0, np.eye(3) * 0.1
    nu_p, nu_v = [0.5, -0.3, 0.2], [0.05, 0.1, -0.02]
    ok_p, ok_v, _, d2p, d2v = a.update_fix(nu_p, Rp, nu_v, Rv, gate_chi2=16.27)
    b.update_states(0, nu_p, Rp)
    v = b.x[3:6]
    b.update_states(3, [1.0 + nu_v[0] - v[0], nu_v[1] - v[1], nu_v[2] - v[2]], Rv)
    assert ok_p and ok_v and 0.0 < d2p < 16.27 and 0.0 < d2v < 16.27
    np.testing.assert_allclose(a.x, b.x, atol=1e-9)
    np.testing.assert_allclose(a.P, b.P, atol=1e-9)


def test_kalman_fix_update_gates_each_block_on_its_own():
    kf = NavKalman()
    kf.initialize([0.0, 0.0, 0.0], np.eye(3), [0.0, 0.0, 0.0], np.eye(3) * 0.01)
    ok_p, ok_v, dx, d2p, d2v = kf.update_fix([0.5, 0.5, 0.5], np.eye(3), [3.0, 0.0, 0.0], np.eye(3) * 0.01,
                                             gate_chi2=16.27)
    assert ok_p and not ok_v and dx[0] == pytest.approx(0.25, abs=0.01)
    # each block's NIS comes back, the refused one's too: consistency.py judges by them
    assert d2p == pytest.approx(3 * 0.25 / 2.0) and d2v == pytest.approx(9.0 / 0.02)


def test_kalman_coasting_grows_the_covariance_and_a_blow_up_is_divergence():
    kf = NavKalman()
    kf.initialize([0.0, 0.0, 0.0], np.eye(3), [5.0, 0.0, 0.0], np.eye(3) * 0.01)
    for _ in range(100):
        kf.move(0.0, 0.0, 0.0, 0.1)
    kf.flush()
    assert kf.x[0] == pytest.approx(50.0) and kf.P[0, 0] > 10.0
    with pytest.raises(Diverged):
        for _ in range(10_000):
            kf.move(0.0, 0.0, 0.0, 1.0)
            kf.flush()


def test_history_interpolates_and_carries_later_corrections():
    h = TrajectoryHistory(window_ns=1_000_000_000)
    for k in range(11):                          # 0.1 s steps, moving east at 2 m/s
        h.append(k * 100_000_000, [0.2 * k, 0.0, 0.0, 2.0, 0.0, 0.0], 0.1 * k)
    p, v, yaw = h.at(250_000_000)
    assert p == pytest.approx([0.5, 0.0, 0.0]) and v == pytest.approx([2.0, 0.0, 0.0])
    assert yaw == pytest.approx(0.25)
    h.correct(dp=[1.0, 0.0, 0.0], dv=[0.0, 0.5, 0.0], dyaw=0.1)
    p, v, yaw = h.at(250_000_000)                # a correction now moves the past too
    assert p == pytest.approx([1.5, 0.0, 0.0]) and v == pytest.approx([2.0, 0.5, 0.0])
    assert yaw == pytest.approx(0.35)
    h.append(11 * 100_000_000, [2.2 + 1.0, 0.0, 0.0, 2.0, 0.5, 0.0], 1.1 + 0.1)
    assert h.at(1_100_000_000)[0] == pytest.approx([3.2, 0.0, 0.0])   # corrected once only
    assert h.at(50_000_000) is None              # older than the window: gone


def test_history_interpolates_yaw_across_plus_minus_pi():
    h = TrajectoryHistory(window_ns=10**9)
    h.append(0, [0.0] * 6, math.pi - 0.1)
    h.append(100_000_000, [0.0] * 6, -math.pi + 0.1)
    assert abs(math.remainder(h.at(50_000_000)[2] - math.pi, 2 * math.pi)) < 1e-9


def test_heading_filter_weighs_courses_and_learns_the_gyro_bias():
    h = HeadingFilter(gyro_psd=1e-6, bias_walk_psd=1e-9)
    assert h.yaw_var == UNKNOWN_VAR
    h.set(math.radians(5.0) ** 2)
    bias_true = math.radians(0.3)                # deg/s the gyro reads too much
    yaw_est, yaw_true = 0.0, 0.0
    for _ in range(600):                         # 60 s at 10 Hz, driving straight
        yaw_est += 0.1 * (bias_true - h.bias)
        h.pending_s += 0.1
        yaw_est += h.correct(yaw_true - yaw_est, math.radians(1.0) ** 2)
    assert h.bias == pytest.approx(bias_true, rel=0.1)
    assert abs(yaw_est) < math.radians(0.3)
    assert h.correct(math.radians(60.0), math.radians(1.0) ** 2, gate_chi2=16.27) is None
