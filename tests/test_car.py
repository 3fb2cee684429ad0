"""The simulated car obeys the bicycle model and its truth is self-consistent."""
import math

import numpy as np
import pymap3d

from viena.common.rotation import euler_from_quat, euler_to_matrix, quat_from_euler, quat_to_matrix
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import IST_ORIGIN


def drive(seconds, dt=0.01):
    car = SimCar()
    return [car.step(dt) for _ in range(int(seconds / dt))]


def test_parked_first_then_drives_at_3_to_5_mps():
    truths = drive(60)
    assert all(t.speed_mps == 0 for t in truths[:900])
    moving = [t.speed_mps for t in truths[2000:]]
    assert 2.9 < min(moving) and max(moving) < 5.1


def test_at_rest_the_accelerometer_feels_plus_g_up():
    t = drive(1)[-1]
    f = t.specific_force_body_mps2
    assert np.allclose(f[:2], 0) and abs(f[2] - 9.80) < 0.01


def test_yaw_rate_is_v_tan_delta_over_wheelbase():
    for t in drive(60)[1500::500]:
        assert math.isclose(t.gyro_body_radps[2], t.speed_mps * math.tan(t.wheel_angle_rad) / 2.2,
                            rel_tol=0.02, abs_tol=2e-3)


def test_wheel_angle_within_29_degrees_and_route_followed():
    truths = drive(120)
    assert max(abs(t.wheel_angle_rad) for t in truths) <= math.radians(29) + 1e-12
    xy = np.array([t.enu_m[:2] for t in truths])
    assert xy[:, 0].min() > -15 and xy[:, 0].max() < 15           # the 24 m wide loop
    assert xy[:, 1].min() > -15 and xy[:, 1].max() < 55


def test_velocity_is_the_derivative_of_position():
    truths = drive(40)
    for a, b in zip(truths[1500:1600], truths[1501:1601]):
        v_num = (b.enu_m - a.enu_m) / 0.01
        assert np.allclose(v_num, 0.5 * (a.vel_enu_mps + b.vel_enu_mps), atol=0.02)


def test_acceleration_is_the_derivative_of_velocity():
    truths = drive(40)
    for a, b in zip(truths[2000:2100], truths[2001:2101]):
        a_num = (b.vel_enu_mps - a.vel_enu_mps) / 0.01
        assert np.allclose(a_num, b.accel_enu_mps2, atol=0.05)


def test_ecef_and_geodetic_agree_with_pymap3d():
    t = drive(30)[-1]
    lat, lon, h = t.geodetic_of()                  # to a tenth of a millimetre
    assert np.allclose(pymap3d.geodetic2ecef(lat, lon, h), t.ecef_of(), atol=1e-4)
    e, n, u = pymap3d.geodetic2enu(lat, lon, h, *IST_ORIGIN)
    assert np.allclose([e, n, u], t.enu_m, atol=1e-4)


def test_lever_arm_points_move_with_the_body():
    t = drive(30)[-1]
    front = t.enu_of([0.0, 1.0, 0.0]) - t.enu_m
    assert np.allclose(front / np.linalg.norm(front), t.vel_enu_mps / np.linalg.norm(t.vel_enu_mps), atol=1e-6)


def test_quaternion_euler_and_matrix_conventions_agree():
    rng = np.random.default_rng(1)
    for yaw, pitch, roll in rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(50, 3)):
        q = quat_from_euler(yaw, pitch, roll)
        assert np.allclose(quat_to_matrix(q), euler_to_matrix(yaw, pitch, roll))
        assert np.allclose(euler_from_quat(q), (yaw, pitch, roll))


def test_yaw_zero_points_north_and_positive_yaw_turns_left():
    r = euler_to_matrix(math.radians(90), 0, 0)
    assert np.allclose(r @ [0, 1, 0], [-1, 0, 0])      # forward points West after a left turn


def test_fast_geodetic_matches_pymap3d_exactly_enough():
    from viena.common.geodesy import LocalFrame
    frame = LocalFrame(*IST_ORIGIN)
    rng = np.random.default_rng(3)
    point = np.zeros(3)
    for _ in range(500):                    # a random walk, as a car moves
        point = point + rng.normal(0, 0.3, 3)
        want = np.array(pymap3d.enu2geodetic(*point, *IST_ORIGIN))
        got = np.array(frame.geodetic_of_enu(*point))
        back = np.array(pymap3d.geodetic2enu(*got, *IST_ORIGIN))
        assert np.allclose(back, point, atol=1e-4)            # within a tenth of a millimetre
        assert np.allclose(got[:2], want[:2], atol=1e-9)


def test_geodetic_of_ecef_follows_a_receiver_anywhere():
    from viena.common.geodesy import geodetic_of_ecef
    rng = np.random.default_rng(5)
    for lat, lon in rng.uniform([-80, -180], [80, 180], size=(20, 2)):
        for step in range(5):
            h = 100.0 + 30.0 * step
            x, y, z = pymap3d.geodetic2ecef(lat + 1e-4 * step, lon, h)
            got = geodetic_of_ecef(x, y, z)
            assert np.allclose(pymap3d.geodetic2ecef(*got), (x, y, z), atol=1e-3)   # a millimetre
    assert np.allclose(geodetic_of_ecef(100.0, 0.0, 0.0), pymap3d.ecef2geodetic(100.0, 0.0, 0.0))
