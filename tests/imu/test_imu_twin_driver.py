"""The VIENA-firmware twin and the driver, over socket:// as on the car over /dev/ttyUSB0."""
from __future__ import annotations

import numpy as np
import pytest

from viena.common.twin.serial_port import SerialEndpoint
from viena.services.imu.driver import Razor, encode_frame
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.simulator import BANNER, NO_ERRORS, RazorBoard, RazorTwin
from viena.services.imu.simulator.scenarios import fixed_truth

pytestmark = pytest.mark.slow  # the twin boots and streams over a socket in real time


def read_n(url: str, n: int, **kwargs):
    with Razor(url, **kwargs) as imu:
        readings = [imu.read(timeout=3.0) for _ in range(n)]
        return readings, list(imu.board_text), imu.stats


def test_twin_boots_then_streams_what_the_car_feels():
    truth = fixed_truth(yaw=0.8, pitch=0.05, roll=-0.1, gyro=(0.01, -0.02, 0.3))
    # the default board without its per-run errors (docs/sensors.md#imu-error-model): its chips as calibrated
    twin = RazorTwin(lambda: truth, RazorBoard(errors=NO_ERRORS), boot_s=0.3, seed=3, rate_hz=300.0)   # 60 frames in 0.2 s
    endpoint = SerialEndpoint(twin).start()
    try:
        readings, text, stats = read_n(endpoint.url, 60)
    finally:
        endpoint.stop()
    assert text == list(BANNER)
    assert stats.crc_errors == stats.bytes_skipped == stats.resyncs == 0
    assert [r.seq for r in readings] == list(range(60))
    assert all(b.t_ns > a.t_ns for a, b in zip(readings, readings[1:]))
    cal = SampleCalibrator(seed_calibration())        # the twin's board is the default one
    frames = [r.frame for r in readings]
    accel = cal.accel_array([f.accel_g for f in frames]).mean(axis=0)
    gyro = cal.gyro_array([f.gyro_dps for f in frames]).mean(axis=0)
    mag = cal.mag_array([f.mag_counts for f in frames]).mean(axis=0)
    assert np.allclose(accel, truth.specific_force_body_mps2, atol=0.03)
    assert np.allclose(gyro, truth.gyro_body_radps, atol=np.radians(0.05))
    assert np.allclose(mag, truth.mag_body_T(), atol=0.6e-6)
    assert np.allclose(frames[-1].euler_deg[0], np.degrees(0.8), atol=0.01)


def test_only_frames_that_crossed_the_line_intact_come_out():
    truth = fixed_truth(yaw=0.3)
    twin = RazorTwin(lambda: truth, boot_s=0.1, seed=4, line_errors=0.2, keep_sent=1000, rate_hz=300.0)
    endpoint = SerialEndpoint(twin).start()
    try:
        readings, _, stats = read_n(endpoint.url, 150)
    finally:
        endpoint.stop()
    intact = {f for f, ok in twin.sent if ok}
    damaged = {f for f, ok in twin.sent if not ok}
    assert len(damaged) > 10 and stats.crc_errors >= len(damaged) // 2
    for r in readings:
        f = r.frame
        assert encode_frame(f.board_id, f.accel_g, f.gyro_dps, f.mag_counts, f.euler_deg) in intact
    seqs = [r.seq for r in readings]
    assert seqs == sorted(seqs) and seqs[-1] - seqs[0] > len(readings) - 1   # lost frames show


def test_reopening_resets_the_board_and_the_count_goes_on():
    twin = RazorTwin(lambda: fixed_truth(yaw=0.3, gyro=(0, 0, 0.1)), boot_s=0.1)
    endpoint = SerialEndpoint(twin).start()
    try:
        imu = Razor(endpoint.url)
        with imu:
            first = [imu.read(timeout=2.0) for _ in range(5)]
        with imu:
            second = [imu.read(timeout=2.0) for _ in range(5)]
            assert imu.stats.text_lines == 2 * len(BANNER)
    finally:
        endpoint.stop()
    assert twin.connects == 2
    assert [r.seq for r in first + second] == list(range(10))
