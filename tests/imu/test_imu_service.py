"""viena-imu as a process: samples and health on zenoh from a twin behind socket://, only
frames with good CRCs published, reconnects, a clean stop."""
from __future__ import annotations

import signal
import threading

import numpy as np
import pytest
from vienatest import wait_until

from viena.common.samples.health import HEALTH
from viena.common.samples.imu import SAMPLE
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.imu.driver import encode_frame
from viena.services.imu.simulator import NO_ERRORS, RazorAhrsTwin, RazorBoard, RazorTwin
from viena.services.imu.simulator.scenarios import fixed_truth

pytestmark = pytest.mark.slow  # the service as a process

KEY = "viena/elettra/imu/razor0"


class Collector:
    def __init__(self, session, key, schema):
        self.items, self.errors = [], []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(key, self._on)
        self._schema = schema

    def _on(self, sample):
        try:
            item = self._schema.decode(sample.payload.to_bytes())
        except Exception as exc:            # noqa: BLE001 - a bad sample is the failure we look for
            self.errors.append(exc)
            return
        with self._lock:
            self.items.append(item)

    def __len__(self):
        return len(self.items)

    def close(self):
        self._sub.undeclare()


def spawn(procs, *args):
    return procs.python("-m", "viena.services.imu.service", *args)


def test_service_publishes_good_frames_only_and_survives_the_device_going_away(router, session, procs, tmp_path):
    truth = fixed_truth(yaw=0.5, gyro=(0.0, 0.0, 0.2))
    twin = RazorTwin(lambda: truth, RazorBoard(errors=NO_ERRORS), boot_s=0.3, seed=11, line_errors=0.1,
                     keep_sent=5000)            # the board as calibrated: no per-run errors
    endpoint = SerialEndpoint(twin).start()
    samples = Collector(session, f"{KEY}/sample", SAMPLE)
    health = Collector(session, f"{KEY}/health", HEALTH)
    proc = spawn(procs, "--connect", router, "--port", endpoint.url, "--calibration", str(tmp_path / "none.toml"))
    try:
        assert wait_until(lambda: len(samples) >= 150, 20), "no samples"
        port = endpoint.port
        endpoint.stop()                                  # the cable is pulled
        assert wait_until(lambda: any(h["errors"].get("port_failures") for h in health.items), 5), \
            "the service did not notice"
        before = len(samples)
        endpoint = SerialEndpoint(twin, port=port).start()
        assert wait_until(lambda: len(samples) > before + 20, 8), "no samples after the device came back"
        assert wait_until(lambda: any(h["counts"].get("reconnects") for h in health.items), 3)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
    finally:
        endpoint.stop()
        samples.close()
        health.close()
    log = proc.stderr.read()
    assert "using the seed's values" in log and "board says: HMC5843 connection successful" in log

    assert not samples.errors
    intact = {f for f, ok in twin.sent if ok}
    for s in samples.items:
        raw = s["raw"]
        frame = encode_frame(s["board_id"], raw["accel_g"], raw["gyro_dps"], raw["mag_counts"], raw["euler_deg"])
        assert frame in intact, "published a frame that did not cross the line intact"
    seqs = [s["seq"] for s in samples.items]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    accel = np.mean([s["accel_mps2"] for s in samples.items], axis=0)
    assert np.allclose(accel, truth.specific_force_body_mps2, atol=0.05)
    gyro = np.mean([s["gyro_radps"] for s in samples.items], axis=0)
    assert np.allclose(gyro, truth.gyro_body_radps, atol=0.002)
    mags = [s["mag_T"] for s in samples.items if s["mag_T"] is not None]
    assert np.allclose(np.mean(mags, axis=0), truth.mag_body_T(), atol=1e-6)
    assert {s["firmware"] for s in samples.items} == {"viena"} and {s["unit"] for s in samples.items} == {"razor0"}

    last = health.items[-1]
    assert last["errors"]["crc_errors"] > 0 and last["errors"]["resyncs"] > 0
    assert last["errors"]["port_failures"] >= 1
    assert any(h["state"]["connected"] and h["rates_hz"].get("samples", 0) > 20 for h in health.items)


def test_service_reads_the_stock_firmware_and_picks_up_a_new_calibration(router, session, procs, tmp_path):
    twin = RazorAhrsTwin(lambda: fixed_truth(gyro=(0, 0, 0)), RazorBoard(errors=NO_ERRORS), boot_s=0.2)   # as calibrated
    endpoint = SerialEndpoint(twin).start()
    samples = Collector(session, f"{KEY}/sample", SAMPLE)
    health = Collector(session, f"{KEY}/health", HEALTH)
    path = tmp_path / "cal.toml"
    proc = spawn(procs, "--connect", router, "--port", endpoint.url, "--firmware", "razor-ahrs",
                 "--calibration", str(path))
    try:
        assert wait_until(lambda: len(samples) >= 20, 20), "no samples"
        assert abs(samples.items[-1]["gyro_radps"][0]) < 0.01
        path.write_text("[razor0]\nfirmware = 'razor-ahrs'\n[razor0.gyro]\nbias_dps = [10.0, 0.0, 0.0]\n")
        assert wait_until(lambda: samples.items[-1]["gyro_radps"][0] < -0.17, 5), "not reloaded"
        path.write_text("[razor0.gyro]\nbias_dps = [1.0]\n")        # broken: keep the last good one
        assert wait_until(lambda: any(h["errors"].get("calibration_errors") for h in health.items), 5), \
            "the broken file was not looked at"
        after_refusal = len(samples)
        assert wait_until(lambda: len(samples) > after_refusal + 5, 5)
        assert samples.items[-1]["gyro_radps"][0] < -0.17
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=5)
        endpoint.stop()
        samples.close()
        health.close()
    s = samples.items[-1]
    assert s["firmware"] == "razor-ahrs" and s["board_id"] is None and s["raw"]["euler_deg"] is None
    assert np.allclose(s["accel_mps2"], [0, 0, 9.8], atol=0.15)
    assert abs(np.linalg.norm(s["mag_T"]) - 43.81e-6) < 2e-6


def test_service_without_a_port_says_so(router, procs):
    proc = spawn(procs, "--connect", router)
    assert proc.wait(timeout=15) == 2
    assert "no port" in proc.stderr.read()
