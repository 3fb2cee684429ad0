"""`viena bench gnss`: the GNSS service's figures.

- driver decode throughput in BESTXYZ frames per second: framing + CRC alone, then with
  the log decoded, then with the fix sample built and encoded (goal >= 20,000 frames/s);
- one `viena-gnss` process's CPU while its receiver logs BESTXYZ at 20 Hz (goal < 2 %);
- time from the last byte of a frame leaving the twin's socket to the fix arriving at a
  zenoh subscriber, p50 and p99;
- recovery: time from the receiver coming back after it vanished to the next fix
  (goal <= 1 s);
- a second receiver: the estimator's horizontal position RMSE on simulated drives with the
  NovAtel twins' error models, fed one receiver (gnss0) or both (gnss0 and gnss1 at the
  sim's lever arms), when the two share one sky (clock, orbit and atmosphere errors; only
  multipath and noise their own, as on the car) and when each draws its own (the twins
  before issue 12); next to the raw error of one receiver's fixes and of the mean of both.
"""
from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from benchmarks.harness import cpu_share, percentile, processes, start_router
from viena.common.config import load_zenoh_config
from viena.common.samples.fix import FIX
from viena.common.twin.serial_port import SerialEndpoint, TwinWrapper
from viena.services.gnss.driver.novatel import (
    BestXyz,
    FrameDecoder,
    Header,
    PositionType,
    SolutionStatus,
    decode_log,
    encode_log,
)
from viena.services.gnss.fixes import fix_from_bestxyz
from viena.services.gnss.simulator import NovatelTwin
from viena.services.gnss.simulator.serve import parked_truth

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

# -- a second receiver ---------------------------------------------------------------------------
#: the antennas, as in compose/sim.toml (body frame: x right, y forward, z up)
ARMS = {"gnss0": (-0.5, 1.0, 1.5), "gnss1": (0.5, 1.0, 1.5)}


def _pair_sensors(drive, rng, truth_fn, shared: bool):
    """The drive's twin sensors with two NovAtel receivers: gnss0's fix is what the drive
    yields, gnss1's fix of the same epoch (and its antenna's true position) waits in
    `.extra`. One sky (CommonErrors) for both, or one each."""
    from benchmarks.simdrive import TwinSensors, _interpolate
    from viena.services.gnss.simulator.errors import CommonErrors, GnssErrorModel, SkyModel
    from viena.services.gnss.simulator.solution import TruthSolver

    class PairSensors(TwinSensors):
        def __init__(self):
            super().__init__(drive, rng, truth_fn)
            sky = CommonErrors(rng) if shared else None
            self.receivers = [(unit, arm, TruthSolver(truth_fn, arm, errors=GnssErrorModel(rng, common=sky),
                                                      sky=SkyModel(rng, outage_interval_s=0.0)))
                              for unit, arm in ARMS.items()]
            self.extra = []

        def gnss(self, t_ns, recent, seq):
            fixes = []
            for unit, arm, solver in self.receivers:
                self.solver = solver
                fixes.append((dict(super().gnss(t_ns, recent, seq), unit=unit),
                              _interpolate(recent, t_ns, arm)[0]))
            self.extra += fixes[1:]
            return fixes[0][0]
    return PairSensors()


def pair_drive(duration_s: float, seed: int, shared: bool) -> list[tuple]:
    """(kind, sample, truth) of a simulated drive with both receivers' fixes."""
    from benchmarks.simdrive import Drive, DriveSamples

    drive = Drive(duration_s=duration_s, seed=seed, lever_arm_m=ARMS["gnss0"])
    samples = DriveSamples(drive)
    samples.sensors = _pair_sensors(drive, samples.rng, samples.car.truth, shared)
    out = []
    for item in samples:
        out.append(item)
        if item[0] == "gnss":
            out += [("gnss", fix, antenna) for fix, antenna in samples.sensors.extra]
            samples.sensors.extra.clear()
    return out


def _raw_h_m(samples, units) -> float:
    """RMS horizontal error of the mean of `units`' fixes at each epoch, in the local frame."""
    import pymap3d

    from viena.services.sim.model.truth import IST_ORIGIN

    by_epoch: dict[int, list] = {}
    for kind, fix, antenna in samples:
        if kind == "gnss" and fix["unit"] in units and fix["valid"]:
            enu = np.array(pymap3d.ecef2enu(*fix["ecef_m"], *IST_ORIGIN))
            by_epoch.setdefault(fix["t"], []).append((enu - antenna)[:2])
    errors = [np.mean(e, axis=0) for e in by_epoch.values() if len(e) == len(units)]
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1))))


def second_receiver(duration_s: float, seeds) -> dict[str, list[float]]:
    """Horizontal RMSE (m) per seed: the estimator with one and with two receivers, and the
    raw fixes, for a shared sky and for independent ones."""
    from benchmarks.estimator import ORIGIN, score

    one = {"origin": list(ORIGIN), "gnss_lever_arm_m": {"gnss0": list(ARMS["gnss0"])}}
    two = {"origin": list(ORIGIN), "gnss_lever_arm_m": {u: list(a) for u, a in ARMS.items()}}
    rows: dict[str, list[float]] = {}
    for seed in seeds:
        for sky in ("shared", "independent"):
            samples = pair_drive(duration_s, seed, shared=sky == "shared")
            alone = [s for s in samples if s[0] == "imu" or s[1]["unit"] == "gnss0"]
            for name, value in (
                    (f"{sky} sky: estimator, one receiver", score(alone, one)["pos_h_m"]),
                    (f"{sky} sky: estimator, two receivers", score(samples, two)["pos_h_m"]),
                    (f"{sky} sky: raw fixes, one receiver", _raw_h_m(samples, {"gnss0"})),
                    (f"{sky} sky: raw fixes, mean of two", _raw_h_m(samples, {"gnss0", "gnss1"}))):
                rows.setdefault(name, []).append(value)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench gnss", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20000)
    parser.add_argument("--seconds", type=float, default=10.0, help="CPU/latency window")
    parser.add_argument("--no-live", action="store_true", help="decode throughput only")
    parser.add_argument("--drive-s", type=float, default=120.0,
                        help="simulated drive per seed for the second-receiver figures (0: skip)")
    parser.add_argument("--seeds", type=int, default=12,
                        help="drives (seeds) for those figures (docs/sensors.md quotes 24)")
    args = parser.parse_args(argv)
    rates = throughput(args.frames)
    for name, rate in rates.items():
        goal = "(goal >= 20,000)" if name != "+fix sample (msgpack)" else "(service path; 20 needed)"
        print(f"BESTXYZ decode, {name:<22} {rate:10,.0f} frames/s  {goal}")
    if args.drive_s > 0:
        rows = second_receiver(args.drive_s, range(1, args.seeds + 1))
        pooled = {name: float(np.sqrt(np.mean(np.square(v)))) for name, v in rows.items()}
        print(f"horizontal RMSE over {args.seeds} drives of {args.drive_s:g} s, m "
              f"(all drives; then each):")
        for name, values in rows.items():
            print(f"  {name:42s} {pooled[name]:5.2f}   " + " ".join(f"{v:4.2f}" for v in values))
        for sky in ("shared", "independent"):
            ratio = pooled[f"{sky} sky: estimator, two receivers"] / pooled[f"{sky} sky: estimator, one receiver"]
            print(f"  {sky} sky: two receivers / one: {ratio:.3f}")
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
