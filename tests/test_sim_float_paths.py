"""The simulated car's and the GNSS twins' arithmetic on Python floats gives the bits of the
numpy and pymap3d calls it stands in for (so a seed gives the same bytes as before it)."""
from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pymap3d
import pytest

from viena.common import rotation
from viena.common.geodesy import LocalFrame
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import IST_ORIGIN, VECTORS, Truth, truth_sample


def _origins(n: int):
    rnd = random.Random(7)
    yield IST_ORIGIN
    for _ in range(n):
        yield rnd.uniform(-89.0, 89.0), rnd.uniform(-180.0, 180.0), rnd.uniform(-100.0, 3000.0)


def test_local_frame_enu_to_ecef_is_pymap3d_bit_for_bit():
    rnd = random.Random(3)
    for origin in _origins(40):
        frame = LocalFrame(*origin)
        for _ in range(50):
            e, n, u = (rnd.uniform(-5e3, 5e3) for _ in range(3))
            assert frame.ecef_of_enu(e, n, u) == tuple(float(v) for v in pymap3d.enu2ecef(e, n, u, *origin))
            assert frame.vector_of_enu(e, n, u) == tuple(float(v) for v in pymap3d.enu2uvw(e, n, u, *origin[:2]))


def test_unit_quat_is_numpys_division_by_the_norm():
    rng = np.random.default_rng(5)
    for _ in range(2000):
        q = rng.standard_normal(4) * 10.0 ** rng.uniform(-3, 3)
        assert rotation.unit_quat(q) == (q / math.sqrt(q.dot(q))).tolist()
    q = rng.standard_normal(4)
    assert rotation.euler_from_quat(q) == rotation.euler_from_unit_quat(*(q / np.linalg.norm(q)).tolist())
    with pytest.warns(RuntimeWarning):
        assert all(math.isnan(v) for v in rotation.unit_quat(np.zeros(4)))     # as numpy, no exception


def _truths():
    car = SimCar(start_time_ns=0)
    for k in range(6000):                   # parked, then round the loop
        truth = car.step(0.01)
        if k % 250 == 0:
            yield truth


def test_truth_fast_paths_are_the_numpy_ones():
    lever = np.array([-0.5, 1.0, 1.5])
    for t in _truths():
        rot = rotation.quat_to_matrix(t.quat)
        assert t.rot.tolist() == rot.tolist()
        assert t.euler_rad == rotation.euler_from_quat(t.quat)
        f_enu = np.asarray(t.accel_enu_mps2, float) + np.array([0.0, 0.0, t.gravity_mps2])
        assert t.specific_force_body_mps2.tolist() == (rot.T @ f_enu).tolist()
        assert t.mag_body_T().tolist() == (rot.T @ (np.array([-1121.5, 26479.8, -34884.7]) * 1e-9)).tolist()
        assert t.enu_of(lever).tolist() == (t.enu_m + rot @ lever).tolist()
        assert t.ecef_of().tolist() == np.array(pymap3d.enu2ecef(*(t.enu_m + rot @ np.zeros(3)), *t.origin)).tolist()
        assert t.ecef_of(lever).tolist() == np.array(pymap3d.enu2ecef(*(t.enu_m + rot @ lever), *t.origin)).tolist()
        assert t.vel_ecef_of(lever).tolist() == np.array(
            pymap3d.enu2uvw(*t.vel_enu_of(lever), *t.origin[:2])).tolist()
        assert t.geodetic_of() == t.frame.geodetic_of_enu(*(t.enu_m + rot @ np.zeros(3)))
        sample = truth_sample(t)
        assert sample["ecef_m"] == t.ecef_of().tolist()
        assert sample["euler_rad"] == list(rotation.euler_from_quat(t.quat))


def test_a_replaced_truth_works_its_rotation_out_afresh():
    t = next(_truths())
    assert t.rot is t.rot                                       # worked out once, kept on t
    turned = dataclasses.replace(t, quat=rotation.quat_from_euler(1.0, 0.0, 0.0))
    assert turned.rot.tolist() == rotation.quat_to_matrix(turned.quat).tolist() != t.rot.tolist()
    assert not t.specific_force_body_mps2.flags.writeable      # shared by its readers: read-only


def test_truth_built_by_hand_still_answers():
    zero = np.zeros(3)
    t = Truth(0, 0.0, IST_ORIGIN, zero, zero, zero, rotation.quat_from_euler(0.3, 0.1, -0.2), zero, 0.0, 0.0)
    assert t.specific_force_body_mps2 == pytest.approx(
        rotation.quat_to_matrix(t.quat).T @ np.array([0.0, 0.0, 9.80665]))
    lat, lon, h = t.geodetic_of()
    assert (lat, lon, h) == pytest.approx(IST_ORIGIN, abs=1e-9)


def test_a_truth_of_floats_reads_as_one_made_of_arrays():
    """Truth.of_floats (the car's) against the constructor given the same vectors as arrays."""
    car = SimCar(start_time_ns=0)
    for k in range(3000):
        t = car.step(0.01)
        if k % 300:
            continue
        arrays = Truth(**{f.name: (np.array(t.floats(f.name)) if f.name in VECTORS else getattr(t, f.name))
                          for f in dataclasses.fields(Truth)})
        assert truth_sample(t) == truth_sample(arrays)
        assert t.mag_body_T().tolist() == arrays.mag_body_T().tolist()
        assert t.mag_body_T((1.0, 2.0, 3.0)).tolist() == arrays.mag_body_T((1.0, 2.0, 3.0)).tolist()
        for name in VECTORS:
            assert isinstance(getattr(t, name), np.ndarray)
            assert getattr(t, name).tolist() == getattr(arrays, name).tolist()
            assert t.floats(name) == arrays.floats(name)
        assert repr(t) == repr(arrays)
        moved = dataclasses.replace(t, t_s=1.0)
        assert moved.enu_m is t.enu_m and moved.t_s == 1.0
