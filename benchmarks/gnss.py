"""`viena bench gnss`: the GNSS service's figures.

- driver decode throughput in BESTXYZ frames per second: framing + CRC alone, then with
  the log decoded, then with the fix sample built and encoded (goal >= 20,000 frames/s);
- one `viena-gnss` process's CPU while its receiver logs BESTXYZ at 20 Hz (goal < 2 %);
- time from the last byte of a frame leaving the twin's socket to the fix arriving at a
  zenoh subscriber, p50 and p99;
- recovery: time from the receiver coming back after it vanished to the next fix
  (goal <= 1 s).
"""
from __future__ import annotations

import argparse
import threading
import time


from viena.common.config import load_zenoh_config
from benchmarks.harness import cpu_share, percentile, processes, start_router
from viena.services.gnss.driver.novatel import (
    BestXyz, FrameDecoder, Header, PositionType, SolutionStatus, decode_log, encode_log,
)
from viena.services.gnss.model.fix import FIX, fix_from_bestxyz
from viena.services.gnss.simulator import NovatelTwin
from viena.services.gnss.simulator.serve import parked_truth
from viena.common.twin.serial_port import SerialEndpoint, TwinWrapper

WEEK_MS = 604_800_000
T_HOST_NS = 1_700_000_000_000_000_000


def bestxyz_stream(n: int) -> bytes:
    frames = []
    for i in range(n):
        data = BestXyz(SolutionStatus.SOL_COMPUTED, PositionType.SINGLE,
                       (4918535.4 + i * 1e-3, -791215.6, 3969669.3), (1.5, 1.5, 2.4),
                       SolutionStatus.SOL_COMPUTED, PositionType.DOPPLER_VELOCITY,
                       (0.01, -0.02, 0.0), (0.03, 0.03, 0.05), "", 0.15, 0.0, 0.0, 9, 8)
        frames.append(encode_log(Header(0, week=2400, milliseconds=50 * i, time_status=180), data))
    return b"".join(frames)


def throughput(n: int = 20000, chunk: int = 4096) -> dict[str, float]:
    """Frames per second at three depths of the path, best of three runs."""
    stream = bestxyz_stream(n)
    pieces = [stream[i:i + chunk] for i in range(0, len(stream), chunk)]

    def run(depth: int) -> float:
        best = 0.0
        for _ in range(3):
            decoder = FrameDecoder()
            t0 = time.perf_counter()
            count = 0
            for piece in pieces:
                for frame in decoder.feed(piece, T_HOST_NS):
                    if depth >= 1:
                        msg = decode_log(frame)
                        if depth >= 2:
                            sample = fix_from_bestxyz(msg, "gnss0", count)
                            FIX.encode(sample)
                    count += 1
            best = max(best, count / (time.perf_counter() - t0))
        return best
    return {"framing+CRC": run(0), "+log decode": run(1), "+fix sample (msgpack)": run(2)}


class StampingTwin(TwinWrapper):
    """Wraps a twin and notes when each epoch's bytes left it (they are sent at once)."""

    def __init__(self, inner):
        super().__init__(inner)
        self.sent_ns: dict[int, int] = {}

    def poll(self, now_s):
        out = self.inner.poll(now_s)
        if out:
            last = self.inner._last_solution
            if last is not None:
                self.sent_ns[last.gps_ms] = time.time_ns()
        return out


def live(seconds: float) -> dict:
    import zenoh

    twin = StampingTwin(NovatelTwin(lambda: TRUTH, seed=1, outage_interval_s=0.0))
    endpoint = SerialEndpoint(twin).start()
    latencies: list[float] = []
    arrivals: list[float] = []
    lock = threading.Lock()

    def on_fix(sample):
        now = time.time_ns()
        fix = FIX.decode(sample.payload.to_bytes())
        sent = twin.sent_ns.get(fix["gps_week"] * WEEK_MS + fix["gps_ms"])
        with lock:
            arrivals.append(time.monotonic())
            if sent is not None:
                latencies.append((now - sent) / 1e6)

    result = {}
    try:
        with processes() as start:
            router = start_router(start)
            gnss = start("-m", "viena.services.gnss.service", "--connect", router,
                         "--port", endpoint.url, "--log-level", "WARNING")
            with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
                sub = session.declare_subscriber("viena/elettra/gnss/gnss0/fix", on_fix)
                _wait(lambda: len(arrivals) > 20, 20.0)
                time.sleep(1.0)                                  # past start-up
                with lock:
                    latencies.clear()
                result["cpu"] = cpu_share(gnss.pid, seconds)
                with lock:
                    result["latency"] = list(latencies)
                # recovery: pull the cable, wait until the service notices, plug it back
                port = endpoint.port
                endpoint.stop()
                time.sleep(1.5)
                endpoint = SerialEndpoint(twin, port=port).start()
                back = time.monotonic()
                with lock:
                    before = len(arrivals)
                _wait(lambda: len(arrivals) > before, 10.0)
                with lock:
                    first = arrivals[before] if len(arrivals) > before else float("nan")
                result["recovery"] = first - back
                sub.undeclare()
    finally:
        endpoint.stop()
    return result


def _wait(predicate, timeout: float) -> None:
    end = time.monotonic() + timeout
    while not predicate() and time.monotonic() < end:
        time.sleep(0.02)


TRUTH = parked_truth()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench gnss", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20000)
    parser.add_argument("--seconds", type=float, default=10.0, help="CPU/latency window")
    parser.add_argument("--no-live", action="store_true", help="decode throughput only")
    args = parser.parse_args(argv)
    rates = throughput(args.frames)
    for name, rate in rates.items():
        goal = "(goal >= 20,000)" if name != "+fix sample (msgpack)" else "(service path; 20 needed)"
        print(f"BESTXYZ decode, {name:<22} {rate:10,.0f} frames/s  {goal}")
    if args.no_live:
        return 0
    r = live(args.seconds)
    lat = r["latency"]
    print(f"viena-gnss CPU at 20 Hz:                {r['cpu'] * 100:6.2f} % of one core  (goal < 2)")
    print(f"last byte -> subscriber latency:        p50 {percentile(lat, 50):.2f} ms, "
          f"p99 {percentile(lat, 99):.2f} ms over {len(lat)} fixes")
    print(f"fixes again after the receiver returns: {r['recovery']:.2f} s  (goal <= 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
