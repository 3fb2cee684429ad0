"""`viena bench imu`: how fast the IMU path is. Prints numbers; asserts nothing.

    decode      FrameDecoder alone, and the driver's full path (decode, stamp, number)
    sample      calibration + sample dict + schema check + msgpack, per sample
    service     viena-imu as a process against the twin at 82.5 Hz: its CPU share, and the
                latency from the twin writing a frame to a subscriber holding the sample

Goals (issue 4): decode >= 50,000 frames/s; sample <= 50 us; service CPU < 3 % of a core.
"""
from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.driver import FrameDecoder, Razor, Reading, encode_frame
from viena.services.imu.driver.frames import decode_frame
from viena.services.imu.model.sample import SAMPLE, SampleBuilder


def _frames(n: int) -> bytes:
    rng = np.random.default_rng(0)
    one = [encode_frame(1, rng.normal(0, 1, 3), rng.normal(0, 20, 3), rng.normal(0, 400, 3),
                        rng.uniform(-180, 180, 3)) for _ in range(1000)]
    return b"".join(one[k % 1000] for k in range(n))


def bench_decode(n: int, chunk: int = 4096) -> dict:
    data = _frames(n)
    decoder = FrameDecoder()
    t = time.perf_counter()
    for k in range(0, len(data), chunk):
        decoder.feed(data[k:k + chunk])
    decode_s = time.perf_counter() - t
    assert decoder.stats.frames == n
    driver = Razor("loop://")                 # never opened: feed its ingest path directly
    t = time.perf_counter()
    now = time.time_ns()
    for k in range(0, len(data), chunk):
        driver._ingest(data[k:k + chunk], now)
        driver._pending.clear()
    driver_s = time.perf_counter() - t
    return {"decoder_frames_per_s": n / decode_s, "driver_frames_per_s": n / driver_s}


def bench_sample(n: int) -> dict:
    builder = SampleBuilder("razor0", "viena", SampleCalibrator(seed_calibration()))
    frame = decode_frame(_frames(1))
    reading = Reading(time.time_ns(), time.time_ns(), 0, frame)
    t = time.perf_counter()
    for _ in range(n):
        builder.build(reading)
    build_s = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(n):
        SAMPLE.encode(builder.build(reading))
    both_s = time.perf_counter() - t
    return {"calibrate_us": build_s / n * 1e6, "calibrate_and_encode_us": both_s / n * 1e6}


# -- the service as a process -------------------------------------------------------------------
def bench_service(seconds: float) -> dict:
    import zenoh

    from viena.common.config import load_zenoh_config
    from benchmarks.harness import cpu_seconds, percentile, processes, start_router
    from viena.services.imu.simulator import RazorTwin
    from viena.services.imu.simulator.scenarios import fixed_truth
    from viena.common.twin.serial_port import SerialEndpoint

    sent: dict[bytes, int] = {}

    class StampingTwin(RazorTwin):
        """Notes when each frame leaves the twin (wall clock, ns)."""
        def _on_line(self, frame: bytes) -> bytes:
            sent[frame] = time.time_ns()
            return super()._on_line(frame)

    truth = fixed_truth(yaw=0.3, gyro=(0, 0, 0.1))
    endpoint = SerialEndpoint(StampingTwin(lambda: truth, boot_s=0.2)).start()
    latencies, lock = [], threading.Lock()

    def on_sample(s) -> None:
        now = time.time_ns()
        d = SAMPLE.decode(s.payload.to_bytes())
        raw = d["raw"]
        frame = encode_frame(d["board_id"], raw["accel_g"], raw["gyro_dps"], raw["mag_counts"], raw["euler_deg"])
        t0 = sent.get(frame)
        if t0 is not None:
            with lock:
                latencies.append((now - t0) / 1e6)

    try:
        with processes() as start:
            router = start_router(start)
            session = zenoh.open(load_zenoh_config(mode="client", connect=[router]))
            sub = session.declare_subscriber("viena/elettra/imu/razor0/sample", on_sample)
            proc = start("-m", "viena.services.imu.service", "--connect", router, "--port", endpoint.url,
                         "--calibration", "", "--log-level", "WARNING")
            try:
                deadline = time.monotonic() + 20
                while not latencies and time.monotonic() < deadline:
                    time.sleep(0.05)
                time.sleep(1.0)                           # let it settle
                with lock:
                    latencies.clear()
                cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
                time.sleep(seconds)
                cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
                with lock:
                    lat = list(latencies)
            finally:
                sub.undeclare()
                session.close()
    finally:
        endpoint.stop()
    if not lat:
        return {"service": "no samples arrived"}
    return {"service_cpu_percent": 100 * (cpu1 - cpu0) / (wall1 - wall0),
            "service_rate_hz": len(lat) / (wall1 - wall0),
            "latency_p50_ms": percentile(lat, 50),
            "latency_p99_ms": percentile(lat, 99)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench imu", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=100_000, help="frames to decode")
    parser.add_argument("--samples", type=int, default=20_000, help="samples to calibrate and encode")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to watch the service")
    parser.add_argument("--no-service", action="store_true", help="skip the service measurement")
    args = parser.parse_args(argv)
    results = {**bench_decode(args.frames), **bench_sample(args.samples)}
    if not args.no_service:
        results.update(bench_service(args.seconds))
    goals = {"decoder_frames_per_s": ">= 50000", "calibrate_and_encode_us": "<= 50",
             "service_cpu_percent": "< 3"}
    for name, value in results.items():
        shown = f"{value:,.1f}" if isinstance(value, float) else str(value)
        goal = f"   (goal {goals[name]})" if name in goals else ""
        print(f"{name:26s} {shown:>12s}{goal}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
