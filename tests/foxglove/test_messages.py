"""viena samples -> Foxglove messages (viena/foxglove_messages.py), read back through the
Foxglove schemas' own protobuf descriptors."""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from foxglove_client import protobuf_decoder

from viena.common.samples.estimator import STATE
from viena.common.samples.fix import FIX
from viena.common.samples.health import HEALTH
from viena.common.samples.truth import TRUTH
from viena.foxglove_messages import Converter, json_bytes
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import truth_sample

T0 = 1_717_236_000_123_456_789


def read(derived):
    """A derived message as its protobuf, parsed by the descriptors its schema carries."""
    schema = type(derived.message).get_schema()
    return protobuf_decoder(schema.name, schema.data)(derived.message.encode())


def fix(**change) -> dict:
    lat, lon, h = 38.7369123456, -9.1395123456, 110.0
    ecef = [float(v) for v in pymap3d.geodetic2ecef(lat, lon, h)]
    sample = {"t": T0, "seq": 1, "unit": "gnss1", "protocol": "novatel", "valid": True,
              "pos_status": "SOL_COMPUTED", "pos_type": "SINGLE", "vel_status": "SOL_COMPUTED",
              "vel_type": "DOPPLER_VELOCITY", "ecef_m": ecef, "ecef_sigma_m": [1.0, 2.0, 3.0],
              "vel_ecef_mps": None, "vel_sigma_mps": None, "lat_deg": lat, "lon_deg": lon, "height_m": h,
              "sats_tracked": 9, "sats_used": 8, "gps_week": 2317, "gps_ms": 1, "t_host": T0,
              "latency_s": 0.0, "vel_latency_s": 0.0}
    sample.update(change)
    return FIX.decode(FIX.encode(sample))


def convert(key: str, schema, sample: dict, converter: Converter | None = None):
    converter = converter or Converter()
    return converter.derived(converter.route(key, schema.encoding), sample)


def test_a_valid_fix_is_the_antennas_location_with_an_enu_covariance():
    out, status = convert("viena/elettra/gnss/gnss1/fix", FIX, fix(enu_sigma_m=[0.5, 0.6, 0.9]))
    assert status.kind == "GnssStatus"                            # its status: tests/foxglove/test_rtk_status.py
    assert out.topic == "viena/elettra/foxglove/gnss/gnss1/location" and out.kind == "LocationFix"
    loc = read(out)
    assert loc.latitude == 38.7369123456 and loc.longitude == -9.1395123456 and loc.altitude == 110.0
    assert (loc.timestamp.seconds, loc.timestamp.nanos) == (T0 // 10**9, T0 % 10**9)
    assert loc.frame_id == "gnss1"
    assert list(loc.position_covariance) == pytest.approx([0.25, 0, 0, 0, 0.36, 0, 0, 0, 0.81])
    assert loc.position_covariance_type == 2                      # DIAGONAL_KNOWN


def test_ecef_sigmas_become_the_same_covariance_seen_along_east_north_up():
    loc = read(convert("viena/elettra/gnss/gnss1/fix", FIX, fix())[0])
    lat, lon = math.radians(38.7369123456), math.radians(-9.1395123456)
    enu_in_ecef = np.array([[-math.sin(lon), math.cos(lon), 0],
                            [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)],
                            [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]])
    expected = enu_in_ecef @ np.diag([1.0, 4.0, 9.0]) @ enu_in_ecef.T
    assert np.allclose(np.reshape(loc.position_covariance, (3, 3)), expected, atol=1e-9)
    assert loc.position_covariance_type == 1                      # APPROXIMATED: cross terms unknown


def test_a_fix_without_a_solution_is_not_put_on_the_map():
    for no_fix in (fix(valid=False), fix(ecef_m=[100.0, 0.0, 0.0])):       # only its status is sent
        assert [d.kind for d in convert("viena/elettra/gnss/gnss1/fix", FIX, no_fix)] == ["GnssStatus"]


def test_the_truth_is_a_pose_a_transform_and_a_location_with_heading_clockwise():
    car = SimCar()
    for _ in range(1500):                                         # parked 10 s, then turning
        truth = car.step(0.01)
    sample = TRUTH.decode(TRUTH.encode(truth_sample(truth)))
    out = {d.kind: d for d in convert("viena/elettra/sim/truth", TRUTH, sample)}
    assert set(out) == {"LocationFix", "PoseInFrame", "FrameTransform"}
    tf = read(out["FrameTransform"])
    assert (tf.parent_frame_id, tf.child_frame_id) == ("enu", "car_truth")
    w, x, y, z = sample["quat"]
    assert [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w] == [x, y, z, w]
    assert [tf.translation.x, tf.translation.y, tf.translation.z] == sample["enu_m"]
    pose = read(out["PoseInFrame"])
    assert pose.frame_id == "enu" and pose.pose.position.x == sample["enu_m"][0]
    loc = read(out["LocationFix"])
    yaw = sample["euler_rad"][0]
    assert math.remainder(loc.heading + yaw, math.tau) == pytest.approx(0.0, abs=1e-12)
    assert 0 <= loc.heading < math.tau
    assert [loc.velocity.x, loc.velocity.y, loc.velocity.z] == sample["vel_enu_mps"]


def test_the_estimator_location_carries_its_full_covariance_and_no_pose_before_a_position():
    state = estimator_state()
    out = {d.kind: d for d in convert("viena/elettra/estimator/state", STATE, state)}
    loc = read(out["LocationFix"])
    assert list(loc.position_covariance) == [4.0, 0.5, 0.1, 0.5, 9.0, 0.2, 0.1, 0.2, 16.0]
    assert loc.position_covariance_type == 3                      # KNOWN
    assert read(out["FrameTransform"]).child_frame_id == "car"
    assert convert("viena/elettra/estimator/state", STATE, {**state, "position_valid": False}) == []


def test_health_errors_that_grow_are_logged_once_each():
    converter = Converter()
    key = "viena/elettra/gnss/gnss0/health"

    def health(t, errors, last_error=None):
        return HEALTH.decode(HEALTH.encode({
            "t": t, "seq": 1, "service": "gnss", "unit": "gnss0", "uptime_s": 1.0, "rates_hz": {},
            "counts": {}, "errors": errors, "last_sample_age_s": None,
            "state": {"last_error": last_error} if last_error else None}))

    first = convert(key, HEALTH, health(T0, {"crc_errors": 2, "silences": 0}), converter)
    assert [read(d).message for d in first] == ["gnss/gnss0: crc_errors +2 since it started (total 2)"]
    assert convert(key, HEALTH, health(T0 + 1, {"crc_errors": 2, "silences": 0}), converter) == []
    [grown] = convert(key, HEALTH, health(T0 + 2, {"crc_errors": 2, "silences": 1}, "no data for 1 s"),
                      converter)
    log = read(grown)
    assert grown.topic == "viena/elettra/foxglove/log" and log.name == "gnss/gnss0"
    assert log.message == ("gnss/gnss0: silences +1 in the last health period (total 1); "
                           "last error: no data for 1 s")
    assert log.level == 4                                         # ERROR


def test_json_text_has_no_nan_and_no_bytes():
    assert json_bytes({"a": 1.5, "b": [1, 2]}) == b'{"a":1.5,"b":[1,2]}'
    assert json_bytes({"a": float("nan"), "b": b"\x01\xff"}) == b'{"a":null,"b":"01ff"}'


def estimator_state() -> dict:
    state = {"t": T0, "seq": 1, "mode": "navigating", "aligned": True, "heading_valid": True,
             "heading_source": "course", "position_valid": True, "standstill": False, "imu_live": True,
             "gnss_live": ["gnss0"], "origin": [38.7369, -9.1395, 100.0], "origin_source": "config",
             "enu_m": [1.0, 2.0, 0.5], "enu_var_m2": [4.0, 9.0, 16.0],
             "enu_cov_m2": [4.0, 0.5, 0.1, 9.0, 0.2, 16.0], "enu_sigma_m": [2.0, 3.0, 4.0],
             "sigma_h_m": 3.1, "sigma_v_m": 4.0, "lat_deg": 38.73692, "lon_deg": -9.13949,
             "height_m": 100.5, "vel_enu_mps": [0.1, 3.0, 0.0], "vel_var_m2ps2": [0.01] * 3,
             "speed_mps": 3.0, "quat": [1.0, 0.0, 0.0, 0.0], "yaw_rad": 0.0, "pitch_rad": 0.0,
             "roll_rad": 0.0, "att_var_rad2": [1e-4] * 3, "rate_body_radps": [0.0] * 3,
             "accel_bias_mps2": [0.0] * 3, "gyro_bias_radps": [0.0] * 3, "gnss_used": 1,
             "gnss_rejected": {}, "input_rejected": {}, "counts": {}}
    return STATE.decode(STATE.encode(state))
