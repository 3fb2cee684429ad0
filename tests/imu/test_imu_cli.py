"""`viena calibrate imu` reading a device port and the running service's samples; twins by name."""
from __future__ import annotations

import threading

import pytest

from viena.common.samples.imu import SAMPLE
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.imu.calibration_cli import main
from viena.services.imu.driver import Frame, Reading
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.model.sample_builder import SampleBuilder
from viena.services.imu.recordings import load_recording
from viena.services.imu.simulator import NO_ERRORS, RazorAhrsTwin, RazorBoard, RazorReplayTwin, RazorTwin, make_twin
from viena.services.imu.simulator.scenarios import fixed_truth


@pytest.mark.slow  # the commands record for 4 s
def test_record_and_fit_from_a_device_port(tmp_path, capsys):
    board = RazorBoard(gyro_bias_dps=(0.25, -0.15, 0.05), errors=NO_ERRORS)   # no drawn turn-on bias on top
    twin = RazorTwin(lambda: fixed_truth(gyro=(0, 0, 0)), board, boot_s=0.1, rate_hz=300.0)
    endpoint = SerialEndpoint(twin).start()
    out = tmp_path / "still.csv"
    try:
        assert main(["record", str(out), "--port", endpoint.url, "--seconds", "1.5"]) == 0
        assert main(["gyro", "--port", endpoint.url, "--seconds", "2.6", "--file", str(tmp_path / "c.toml")]) == 0
    finally:
        endpoint.stop()
    assert len(load_recording(out)) > 200
    report = capsys.readouterr().out
    assert "gyro bias [deg/s]  x +0.25" in report and "y -0.15" in report
    assert "bias_dps = [0.25" in (tmp_path / "c.toml").read_text()


def test_fit_live_from_the_running_services_samples(router, session, capsys):
    """Publish samples as viena-imu does, and let the command collect their raw values."""
    import zenoh

    from viena.common.keys import Keys

    builder = SampleBuilder("razor0", "viena", SampleCalibrator(seed_calibration()))
    pub = session.declare_publisher(Keys().key("imu", "razor0", "sample"),
                                           encoding=zenoh.Encoding(SAMPLE.encoding))
    stop = threading.Event()

    def publish():
        seq = 0
        while not stop.wait(0.005):
            frame = Frame(1, (0.0, 0.0, 1.0), (0.1, -0.3, 0.2), (-250.0, 180.0, -350.0), (0.0, 0.0, 0.0))
            pub.put(SAMPLE.encode(builder.build(Reading(1_800_000_000_000_000_000 + seq, 0, seq, frame))))
            seq += 1

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        rc = main(["gyro", "--live", "--seconds", "1.5", "--connect", router, "--dry-run"])
    finally:
        stop.set()
        thread.join()
        pub.undeclare()
    assert rc == 0
    out = capsys.readouterr().out
    assert "x +0.1000  y -0.3000  z +0.2000" in out and "dry run" in out


def test_one_input_only(tmp_path, capsys):
    assert main(["gyro", "--file", str(tmp_path / "c.toml")]) == 2
    assert "exactly one" in capsys.readouterr().err


def test_twins_by_name():
    truth = lambda: fixed_truth(yaw=0.3, gyro=(0, 0, 0.1))  # noqa: E731
    assert isinstance(make_twin("razor", truth), RazorTwin)
    assert isinstance(make_twin("razor-ahrs", truth), RazorAhrsTwin)
    replay = make_twin("replay:speed_10hz")
    assert isinstance(replay, RazorReplayTwin) and len(replay.recording) > 5000
    with pytest.raises(ValueError, match="unknown IMU twin"):
        make_twin("gyroscope", truth)
