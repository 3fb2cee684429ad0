"""Frames and conventions (docs/frames.md) against the guide's printed equations, pymap3d
and the car.

The guide's eq. 5.2 (docs/frames.md#ecef-to-enu) is written out here with its first-row
typo fixed ([-sin lon, cos lon, 0]), its eqs. 5.4, 5.8 and 5.10
(docs/frames.md#rotation-matrices-and-euler-angles, docs/frames.md#quaternions) as printed,
and each is checked against what the estimator uses. The helpers keep the guide's
equation numbers in their names on purpose: they reproduce what it prints.
"""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from viena.common.geodesy import LocalFrame
from viena.common.rotation import euler_from_quat, euler_to_matrix, quat_from_euler, quat_multiply, quat_to_matrix
from viena.services.estimator.angles import (
    forward_yaw,
    quat_from_yaw_pitch_roll,
    tilt_from_specific_force,
    yaw_pitch_roll,
)
from viena.services.estimator.heading import course_yaw
from viena.services.estimator.madgwick import attitude_from_vectors

IST = (38.7369, -9.1395, 100.0)
angles = st.floats(-math.pi, math.pi, allow_nan=False)
tilts = st.floats(-1.4, 1.4, allow_nan=False)


def seed_eq_5_2(lat_deg: float, lon_deg: float) -> np.ndarray:
    """ECEF -> ENU rotation, the guide's eq. 5.2 (lambda = longitude, phi = latitude), typo
    fixed (docs/frames.md#ecef-to-enu)."""
    lam, phi = math.radians(lon_deg), math.radians(lat_deg)
    return np.array([
        [-math.sin(lam), math.cos(lam), 0.0],            # the guide prints cos(phi) here
        [-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi)],
        [math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi)],
    ])


def seed_eq_5_4(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """^b_a R as printed: world -> body, the transpose of our body -> world."""
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch),
                              math.cos(roll), math.sin(roll))
    return np.array([
        [cy * cp, sy * cp, -sp],
        [cy * sp * sr - sy * cr, cy * cr + sy * sp * sr, cp * sr],
        [sy * sr + cy * sp * cr, sy * sp * cr - cy * sr, cp * cr],
    ])


def seed_eq_5_8(a, b) -> np.ndarray:
    a1, a2, a3, a4 = a
    b1, b2, b3, b4 = b
    return np.array([a1 * b1 - a2 * b2 - a3 * b3 - a4 * b4,
                     a1 * b2 + a2 * b1 + a3 * b4 - a4 * b3,
                     a1 * b3 - a2 * b4 + a3 * b1 + a4 * b2,
                     a1 * b4 + a2 * b3 - a3 * b2 + a4 * b1])


def conj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


# -- ECEF and ENU (eq. 5.1, 5.2, table 5.1) -----------------------------------------------------
@pytest.mark.parametrize("lat, lon", [IST[:2], (0.0, 0.0), (-33.9, 151.2), (64.1, -21.9), (38.7, 179.9)])
def test_seed_eq_5_2_with_its_typo_fixed_is_pymap3d_rotation(lat, lon):
    frame = LocalFrame(lat, lon, 50.0)
    np.testing.assert_allclose(frame.rot_ecef_to_enu, seed_eq_5_2(lat, lon), atol=1e-12)
    # ... and the printed first row is not a rotation at all
    printed = seed_eq_5_2(lat, lon)
    printed[0, 1] = math.cos(math.radians(lat))
    assert abs(np.linalg.det(printed) - 1.0) > 1e-3 or lat == 0.0


@settings(max_examples=100, deadline=None)
@given(st.floats(-3000, 3000), st.floats(-3000, 3000), st.floats(-50, 50))
def test_enu_of_ecef_is_pymap3d_to_the_millimetre(e, n, u):
    frame = LocalFrame(*IST)
    ecef = pymap3d.enu2ecef(e, n, u, *IST)
    np.testing.assert_allclose(frame.enu_of_ecef(ecef), pymap3d.ecef2enu(*ecef, *IST), atol=1e-3)
    np.testing.assert_allclose(frame.enu_of_ecef(ecef), (e, n, u), atol=1e-3)


@settings(max_examples=100, deadline=None)
@given(st.floats(-5000, 5000), st.floats(-5000, 5000), st.floats(-100, 100))
def test_geodetic_of_enu_is_pymap3d_to_a_millimetre(e, n, u):
    frame = LocalFrame(*IST)
    lat, lon, h = frame.geodetic_of_enu(e, n, u)
    lat2, lon2, h2 = pymap3d.enu2geodetic(e, n, u, *IST)
    assert abs(lat - lat2) * 111_000 < 1e-3 and abs(lon - lon2) * 87_000 < 1e-3 and abs(h - h2) < 1e-3


def test_first_fix_origin_and_the_lever_free_velocity_rotation():
    frame = LocalFrame.at_ecef(pymap3d.geodetic2ecef(*IST))
    np.testing.assert_allclose(frame.origin, IST, atol=1e-9)
    east_ecef = pymap3d.enu2uvw(1.0, 0.0, 0.0, *IST[:2])
    np.testing.assert_allclose(frame.vector_to_enu(east_ecef), (1, 0, 0), atol=1e-12)
    cov = frame.cov_to_enu((2.0, 2.0, 2.0))
    np.testing.assert_allclose(cov, np.eye(3) * 4.0, atol=1e-12)      # isotropic stays isotropic


# -- rotations and quaternions (eq. 5.4, 5.8, 5.10: docs/frames.md#quaternions) -------------------
@settings(max_examples=100, deadline=None)
@given(angles, tilts, angles)
def test_seed_eq_5_4_is_the_transpose_of_our_body_to_world(yaw, pitch, roll):
    r = euler_to_matrix(yaw, pitch, roll)
    np.testing.assert_allclose(seed_eq_5_4(yaw, pitch, roll), r.T, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(quat_from_euler(yaw, pitch, roll)), r, atol=1e-12)
    back = np.subtract(euler_from_quat(quat_from_euler(yaw, pitch, roll)), (yaw, pitch, roll))
    np.testing.assert_allclose(np.angle(np.exp(1j * back)), 0.0, atol=1e-9)   # -pi and pi are one yaw


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-2, 2), min_size=8, max_size=8))
def test_seed_eq_5_8_is_the_hamilton_product(v):
    a, b = np.array(v[:4]), np.array(v[4:])
    np.testing.assert_allclose(quat_multiply(a, b), seed_eq_5_8(a, b), atol=1e-12)
    assert seed_eq_5_8([0, 1, 0, 0], [0, 0, 1, 0]).tolist() == [0, 0, 0, 1]   # ij = k (eq. 5.7b)


@settings(max_examples=100, deadline=None)
@given(angles, tilts, angles, st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_seed_eq_5_10_rotates_vectors_as_the_matrix_does(yaw, pitch, roll, v):
    q = quat_from_euler(yaw, pitch, roll)
    rotated = seed_eq_5_8(seed_eq_5_8(q, [0.0, *v]), conj(q))
    assert abs(rotated[0]) < 1e-9
    np.testing.assert_allclose(rotated[1:], quat_to_matrix(q) @ v, atol=1e-9)
    # eq. 5.10 read the other way round (q* v q) takes world vectors into the body
    back = seed_eq_5_8(seed_eq_5_8(conj(q), [0.0, *rotated[1:]]), q)
    np.testing.assert_allclose(back[1:], v, atol=1e-9)


# -- the car's frame ----------------------------------------------------------------------------
def test_at_yaw_zero_the_car_points_north_and_yaw_turns_it_left():
    forward = np.array([0.0, 1.0, 0.0])                   # body y
    np.testing.assert_allclose(euler_to_matrix(0, 0, 0) @ forward, (0, 1, 0), atol=1e-12)
    np.testing.assert_allclose(euler_to_matrix(math.pi / 2, 0, 0) @ forward, (-1, 0, 0), atol=1e-12)
    # the compass heading (clockwise, = -yaw) of these yaws: tests/pilot/test_pilot_guidance.py
    assert course_yaw(0.0, 5.0) == 0.0
    assert course_yaw(-5.0, 0.0) == pytest.approx(math.pi / 2)
    assert course_yaw(3.0, 0.0) == pytest.approx(-math.pi / 2)


@settings(max_examples=100, deadline=None)
@given(angles, st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))
def test_still_alignment_recovers_the_attitude(yaw, pitch, roll):
    r = euler_to_matrix(yaw, pitch, roll)
    field = np.array([-1121.5, 26479.8, -34884.7]) * 1e-9
    declination = math.atan2(field[0], field[1])
    q = attitude_from_vectors(r.T @ [0, 0, 9.8], r.T @ field, declination)
    np.testing.assert_allclose(quat_to_matrix(q), r, atol=1e-9)
    y, p, rr = euler_from_quat(attitude_from_vectors(r.T @ [0, 0, 9.8]))
    assert (y, p, rr) == pytest.approx((0.0, pitch, roll), abs=1e-9)


# -- the state's angles (viena.estimator.state/2, issue 13 item 6) ---------------------------------
@settings(max_examples=100, deadline=None)
@given(angles, tilts, angles)
def test_state_angles_are_yaw_then_pitch_about_right_then_roll_about_forward(yaw, pitch, roll):
    c, s = math.cos, math.sin
    rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, c(pitch), -s(pitch)], [0, s(pitch), c(pitch)]])    # about right
    ry = np.array([[c(roll), 0, s(roll)], [0, 1, 0], [-s(roll), 0, c(roll)]])        # about forward
    q = quat_from_yaw_pitch_roll(yaw, pitch, roll)
    np.testing.assert_allclose(quat_to_matrix(q), rz @ rx @ ry, atol=1e-12)
    np.testing.assert_allclose(yaw_pitch_roll(q), (yaw, pitch, roll), atol=1e-9)
    r = quat_to_matrix(q)
    # pitch is the forward axis's elevation, yaw its heading: whatever the roll
    forward = r[:, 1]
    assert math.asin(forward[2]) == pytest.approx(pitch, abs=1e-9)
    assert abs(math.remainder(forward_yaw(r.ravel()) - yaw, math.tau)) < 1e-9
    assert tilt_from_specific_force(*(r.T @ [0, 0, 9.8])) == pytest.approx((pitch, roll), abs=1e-9)


def test_nose_up_is_positive_pitch_and_right_side_down_is_positive_roll():
    nose_up = quat_from_yaw_pitch_roll(0.0, math.radians(5), 0.0)
    assert (quat_to_matrix(nose_up) @ [0, 1, 0])[2] > 0          # forward points up
    right_down = quat_from_yaw_pitch_roll(0.0, 0.0, math.radians(5))
    assert (quat_to_matrix(right_down) @ [1, 0, 0])[2] < 0       # right points down


@pytest.mark.parametrize("pitch_deg, roll_deg", [(4.0, 0.0), (0.0, 3.0), (-2.0, 1.5)])
def test_the_estimators_state_names_the_parked_cars_tilt_by_its_axes(pitch_deg, roll_deg):
    from viena.services.estimator.estimator import Estimator

    q = quat_from_yaw_pitch_roll(0.3, math.radians(pitch_deg), math.radians(roll_deg))
    f = quat_to_matrix(q).T @ [0.0, 0.0, 9.80665]
    est = Estimator()
    for k in range(300):                                          # 3.6 s parked, no field
        est.add_imu({"t": 1_717_236_000_000_000_000 + k * 12_121_212, "accel_mps2": list(f),
                     "gyro_radps": [0.0, 0.0, 0.0], "mag_T": None})
    s = est.state()
    assert s["aligned"]
    assert math.degrees(s["pitch_rad"]) == pytest.approx(pitch_deg, abs=0.05)
    assert math.degrees(s["roll_rad"]) == pytest.approx(roll_deg, abs=0.05)
