"""The typed IMU sample: what a consumer (the estimator) reads of a viena.imu.sample/1, from
viena's own IMU service or from any source that publishes the fields the README lists."""
from __future__ import annotations

import math

import pytest

from viena.common.samples.imu import SAMPLE, ImuSample, read_sample
from viena.common.schema import FieldError
from viena.services.imu.driver import Frame, Reading
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.model.sample_builder import SampleBuilder

T = 1_800_000_000_000_000_000


def test_a_sample_viena_publishes_reads_as_it_is():
    builder = SampleBuilder("razor0", "viena", SampleCalibrator(seed_calibration()))
    frame = Frame(1, (0.0, 0.0, 1.0), (0.1, -0.3, 0.2), (-250.0, 180.0, -350.0), (0.0, 0.0, 0.0))
    sample = SAMPLE.decode(SAMPLE.encode(builder.build(Reading(T, 0, 7, frame))))
    imu = read_sample(sample)
    assert isinstance(imu, ImuSample)
    assert imu == (T, "razor0", sample["accel_mps2"], sample["gyro_radps"], sample["mag_T"])
    assert imu.accel_mps2[2] == pytest.approx(9.8, abs=0.2)


def test_a_sample_from_another_source_needs_only_the_fields_the_readme_lists():
    imu = read_sample({"t": T, "accel_mps2": (0, 0, 9.8), "gyro_radps": [0.0, 0.0, 0.01], "mag_T": None})
    assert imu.unit == "imu" and imu.mag_T is None
    assert imu.accel_mps2 == [0.0, 0.0, 9.8] and all(type(v) is float for v in imu.accel_mps2)
    assert read_sample({"t": T, "accel_mps2": [0.0, 0.0, 9.8], "gyro_radps": [0.0] * 3}).mag_T is None


@pytest.mark.parametrize("change, field, not_finite", [
    ({"accel_mps2": [0.0, math.nan, 9.8]}, "accel_mps2", True),
    ({"mag_T": [1e-5, -math.inf, 0.0]}, "mag_T", True),
    ({"gyro_radps": [0.0, 0.0]}, "gyro_radps", False),
    ({"accel_mps2": ["0", 0.0, 9.8]}, "accel_mps2", False),
    ({"unit": 3}, "unit", False),
    ({"t": 1.8e18}, "t", False),
])
def test_a_wrong_field_is_named(change, field, not_finite):
    sample = {"t": T, "unit": "razor0", "accel_mps2": [0.0, 0.0, 9.8], "gyro_radps": [0.0] * 3}
    with pytest.raises(FieldError, match=field) as caught:
        read_sample({**sample, **change})
    assert (caught.value.field, caught.value.not_finite) == (field, not_finite)
