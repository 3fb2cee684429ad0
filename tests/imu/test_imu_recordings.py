"""The real parked-car recordings (traction motor without current, at 0, 10 and 20 Hz):
what the default calibration (docs/sensors.md#default-calibration) makes of them, their
magnetometer glitches, and their replay through the twin as firmware frames."""
from __future__ import annotations

import numpy as np
import pytest

from viena.common.samples.imu import SAMPLE
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.imu.driver import Frame, Razor, Reading
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.model.glitch import MagGlitchFilter
from viena.services.imu.model.sample_builder import SampleBuilder
from viena.services.imu.recordings import PARKED, load_parked
from viena.services.imu.simulator import BANNER, RazorReplayTwin
from viena.services.imu.simulator.scenarios import Script, record_twin

G_LISBON = 9.8006          # WGS84 normal gravity at IST, 100 m
SEED = SampleCalibrator(seed_calibration())


@pytest.mark.parametrize("name", PARKED)
def test_calibrated_acceleration_of_the_parked_car_is_g(name):
    """Stated tolerance: the mean |a| within 0.3 % of g, 99 % of samples within 5 %
    (the motor at 10-20 Hz shakes the car by up to 0.05 g)."""
    rec = load_parked(name)
    size = np.linalg.norm(SEED.accel_array(rec.accel_g), axis=1)
    assert abs(size.mean() / G_LISBON - 1) < 0.003
    assert np.percentile(np.abs(size / G_LISBON - 1), 99) < 0.05


@pytest.mark.parametrize("name", PARKED)
def test_parked_gyro_reads_zero_and_mag_reads_lisbon(name):
    rec = load_parked(name)
    assert np.all(np.abs(np.degrees(SEED.gyro_array(rec.gyro_dps)).mean(axis=0)) < 0.02)
    mag = SEED.mag_array(rec.mag_counts)
    f = MagGlitchFilter()
    good = np.array([f.accept(m) for m in mag])
    assert np.linalg.norm(mag[good], axis=1).mean() == pytest.approx(43.81e-6, rel=0.05)


@pytest.mark.parametrize("name", PARKED)
def test_the_glitch_filter_removes_exactly_the_hmc5843_misreads(name):
    rec = load_parked(name)
    misread = np.any(np.abs(rec.mag_counts - np.median(rec.mag_counts, axis=0)) > 60, axis=1)
    f = MagGlitchFilter()
    accepted = np.array([f.accept(m) for m in SEED.mag_array(rec.mag_counts)])
    assert misread.sum() >= 10
    assert np.array_equal(~accepted, misread)


def test_replay_sends_the_recording_as_firmware_frames():
    rec = load_parked("nocurrent")
    start = len(rec) - 30
    twin = RazorReplayTwin(rec, boot_s=0.1, rate_hz=400.0, start=start)   # fast, to wrap around
    endpoint = SerialEndpoint(twin).start()
    try:
        with Razor(endpoint.url) as imu:
            readings = [imu.read(timeout=2.0) for _ in range(60)]
            text = list(imu.board_text)
            stats = imu.stats
    finally:
        endpoint.stop()
    assert text == list(BANNER)
    assert stats.crc_errors == stats.bytes_skipped == 0
    rows = [(start + k) % len(rec) for k in range(60)]
    got = np.array([r.frame.accel_g + r.frame.gyro_dps + r.frame.mag_counts + r.frame.euler_deg
                    for r in readings])
    want = np.hstack([rec.accel_g, rec.gyro_dps, rec.mag_counts, rec.euler_deg])[rows]
    assert np.allclose(got, want, atol=1e-4)
    assert {r.frame.board_id for r in readings} == {1}
    assert [r.seq for r in readings] == list(range(60))


def test_samples_from_the_replay_validate_and_glitches_have_no_field():
    rec = load_parked("speed_20hz")
    twin = RazorReplayTwin(rec, boot_s=0.0, rate_hz=1000.0, loop=False)
    replayed = record_twin(twin, Script(lambda t: (0, 0, 0), len(rec) / 1000.0 + 0.1))
    assert len(replayed) == len(rec)
    builder = SampleBuilder("razor0", "viena", SEED)
    nones = 0
    for i in range(len(replayed)):
        frame = Frame(1, tuple(replayed.accel_g[i]), tuple(replayed.gyro_dps[i]),
                      tuple(replayed.mag_counts[i]), tuple(replayed.euler_deg[i]))
        sample = SAMPLE.decode(SAMPLE.encode(builder.build(Reading(1_800_000_000_000_000_000 + i, 0, i, frame))))
        nones += sample["mag_T"] is None
        assert sample["raw"]["mag_counts"] == list(frame.mag_counts)
    assert nones == builder.mag_filter.rejected >= 30
