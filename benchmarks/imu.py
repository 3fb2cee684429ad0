"""`viena bench imu`: how fast the IMU path is. Prints numbers; asserts nothing.

    decode      FrameDecoder alone, and the driver's full path (decode, stamp, number)
    damage      real-shaped frames (the car's parked recordings) cut short, missing bytes,
                with bytes inserted or a bit flipped: false frames and lost whole frames
                per 100,000 damaged frames, for three ways the bytes reach the host (the
                firmware's pause after every frame; bursts of any size, the line pausing
                after each; bursts back to back)
    alignment   `viena calibrate imu mount|time` on simulated three-minute drives: the Razor
                twin's board screwed in at known rotations (axis swaps plus a few degrees),
                its stamps late or early by known amounts; the worst errors over the seeds
    sample      calibration + sample dict + schema check + msgpack, per sample
    service     viena-imu as a process against the twin at 82.5 Hz: its CPU share, and the
                latency from the twin writing a frame to a subscriber holding the sample

Goals (issues 4, 12): decode >= 50,000 frames/s; 0 false frames per 100k damaged;
sample <= 50 us; service CPU < 3 % of a core; mount within 0.5 deg; time offset within 20 ms.
"""
from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from viena.common.samples.imu import SAMPLE
from viena.services.imu.driver import FRAME_SIZE, FrameDecoder, Razor, Reading, encode_frame
from viena.services.imu.driver.frames import decode_frame
from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
from viena.services.imu.model.sample_builder import SampleBuilder


def _frames(n: int) -> bytes:
    rng = np.random.default_rng(0)
    one = [encode_frame(1, rng.normal(0, 1, 3), rng.normal(0, 20, 3), rng.normal(0, 400, 3),
                        rng.uniform((-180, -90, -180), (180, 90, 180))) for _ in range(1000)]
    return b"".join(one[k % 1000] for k in range(n))


def bench_decode(n: int, chunk: int = 4096) -> dict:
    data = _frames(n)
    decoder = FrameDecoder()
    t = time.perf_counter()
    for k in range(0, len(data), chunk):
        decoder.feed(data[k:k + chunk])
    decoder.silence()
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


def bench_damage(damaged: int, rate: float = 0.25, seed: int = 12) -> dict:
    """False frames and lost whole frames per 100k damaged frames, per delivery."""
    from viena.services.imu.simulator.line import damage, deliver, real_shaped_frames

    rng = np.random.default_rng(seed)
    pool = real_shaped_frames()
    n = int(damaged / rate)
    stream = damage([pool[k % len(pool)] for k in range(n)], rate, rng, pool)
    data, sent = stream.data, set(pool)
    per_100k = 1e5 / stream.damaged
    results = {"damaged_frames": stream.damaged}
    for name, how, pause_p in (("pauses", "pauses", 1.0), ("bursts_paused", "bursts", 1.0),
                               ("bursts", "bursts", 0.0)):
        decoder = FrameDecoder()
        offsets = []
        for chunk, paused in deliver(stream.units, how, pause_p, rng):
            offsets += [o for o, _ in decoder.feed(chunk)]
            if paused:
                offsets += [o for o, _ in decoder.silence()]
        offsets += [o for o, _ in decoder.silence()]
        false = sum(o not in stream.whole_at and data[o:o + FRAME_SIZE] not in sent for o in offsets)
        lost = len(set(stream.whole_at) - set(offsets))
        results[f"false_per_100k_damaged_{name}"] = false * per_100k
        results[f"whole_lost_per_100k_damaged_{name}"] = lost * per_100k
    return results


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

    from benchmarks.harness import cpu_seconds, percentile, processes, start_router
    from viena.common.config import load_zenoh_config
    from viena.common.twin.serial_port import SerialEndpoint
    from viena.services.imu.simulator import RazorTwin
    from viena.services.imu.simulator.scenarios import fixed_truth

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


MOUNTS = ((90.0, 0.0, 0.0), (-93.5, 4.2, -2.7), (178.0, -3.0, 5.5), (6.0, 2.0, 180.0))
OFFSETS_S = (-0.5, -0.2, -0.05, 0.05, 0.2, 0.5)
LEVER_ARM_M = (0.0, 1.0, 1.5)          # simdrive's antenna, from the rear axle


def mounted_drive(mount_zyx_deg=(0.0, 0.0, 0.0), seconds: float = 180.0, seed: int = 4):
    """(imu samples, fixes) of a simulated drive with the board mounted at `mount_zyx_deg`:
    the Razor twin's board model and the NovAtel twin's fixes, offline."""
    from benchmarks.simdrive import Drive, DriveSamples
    from viena.services.imu.simulator import RazorBoard

    samples = DriveSamples(Drive(duration_s=seconds, seed=seed))
    samples.sensors.board = RazorBoard(mount_zyx_deg=mount_zyx_deg)
    imu, fixes = [], []
    for kind, sample, _ in samples:
        (imu if kind == "imu" else fixes).append(sample)
    return imu, fixes


def bench_alignment(seeds: int) -> dict:
    from viena.services.imu.drive_calibration import DriveData, measure_mount
    from viena.services.imu.model.motion import gnss_motion
    from viena.services.imu.model.mount import Mount
    from viena.services.imu.model.time_offset import estimate_time_offset

    cal = seed_calibration()
    mount_errors, time_errors = [], []
    for seed in range(1, seeds + 1):
        for mount in MOUNTS:
            imu, fixes = mounted_drive(mount, seed=seed)
            drive = DriveData(np.array([s["t"] for s in imu]) * 1e-9,
                              np.array([s["raw"]["accel_g"] for s in imu]),
                              np.array([s["raw"]["gyro_dps"] for s in imu]), fixes, "gnss0")
            import contextlib
            import io
            with contextlib.redirect_stdout(io.StringIO()):
                found, _ = measure_mount(drive, cal, LEVER_ARM_M)
            mount_errors.append(Mount(mount).angle_to_deg(found.mount))
        imu, fixes = mounted_drive(seed=seed)
        t = np.array([s["t"] for s in imu]) * 1e-9
        accel = np.array([s["accel_mps2"] for s in imu])
        gyro = np.array([s["gyro_radps"] for s in imu])
        motion = gnss_motion(fixes, LEVER_ARM_M)
        for late in OFFSETS_S:
            found = estimate_time_offset(t + late, accel, gyro, motion)
            time_errors.append(abs(found.offset_s + late))
    return {"mount_error_deg_worst": max(mount_errors),
            "mount_error_deg_mean": float(np.mean(mount_errors)),
            "time_offset_error_ms_worst": max(time_errors) * 1e3,
            "time_offset_error_ms_mean": float(np.mean(time_errors)) * 1e3}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench imu", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=100_000, help="frames to decode")
    parser.add_argument("--damaged", type=int, default=100_000, help="damaged frames to decode")
    parser.add_argument("--samples", type=int, default=20_000, help="samples to calibrate and encode")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to watch the service")
    parser.add_argument("--no-service", action="store_true", help="skip the service measurement")
    parser.add_argument("--alignment-seeds", type=int, default=3,
                        help="simulated drives per mount for the mount and clock figures")
    args = parser.parse_args(argv)
    results = {**bench_decode(args.frames), **bench_damage(args.damaged), **bench_sample(args.samples),
               **bench_alignment(args.alignment_seeds)}
    if not args.no_service:
        results.update(bench_service(args.seconds))
    goals = {"decoder_frames_per_s": ">= 50000", "calibrate_and_encode_us": "<= 50",
             "service_cpu_percent": "< 3", "mount_error_deg_worst": "<= 0.5",
             "time_offset_error_ms_worst": "<= 20", **{f"false_per_100k_damaged_{d}": "0"
                                              for d in ("pauses", "bursts_paused", "bursts")}}
    for name, value in results.items():
        shown = f"{value:,.1f}" if isinstance(value, float) else str(value)
        goal = f"   (goal {goals[name]})" if name in goals else ""
        print(f"{name:38s} {shown:>12s}{goal}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
