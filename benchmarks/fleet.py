"""`viena bench fleet`: several simulated cars through one router, next to the real one.

    viena bench fleet [--cars 5] [--seconds 60] [--baseline-seconds 10]

The sim profile runs the car (`elettra`: the simulated car, its device services, the
estimator) on its router; an observer subscribes to every key of every car, as a laptop
watching the fleet would. First the car alone (--baseline-seconds), then with --cars more
simulated cars (`viena-sim --car carN`: truth at 100 Hz and health, no devices) on the same
router (--seconds). Prints, for the real car, each key's rate alone and with the fleet
(goal: held within 1 %) and its sequence gaps (goal 0); each fleet car's truth rate; and
the router's CPU share and memory, alone, with the fleet, and per added car.
"""
from __future__ import annotations

import argparse
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import msgpack

from benchmarks.faults import pids
from benchmarks.harness import cpu_seconds, processes, rss_mb
from benchmarks.security import open_as, sim_car

CAR = "viena/elettra/"
#: the real car's keys whose rates are compared (health: one per second per service)
CAR_KEYS = ["sim/truth", "gnss/gnss0/fix", "gnss/gnss1/fix", "imu/razor0/sample", "steering/state",
            "estimator/state"]


class Traffic:
    """Every sample of every car, counted per key; the real car's sequence gaps per key."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.counts: dict[str, int] = defaultdict(int)
        self.gaps: dict[str, int] = defaultdict(int)
        self._last_seq: dict[str, int] = {}
        self._sub = session.declare_subscriber("viena/**", self._on)

    def _on(self, sample) -> None:
        key = str(sample.key_expr)
        seq = None
        if key.startswith(CAR):
            try:
                seq = msgpack.unpackb(sample.payload.to_bytes()).get("seq")
            except Exception:
                seq = None
        with self.lock:
            self.counts[key] += 1
            if isinstance(seq, int):
                last = self._last_seq.get(key)
                if last is not None and seq > last + 1:
                    self.gaps[key] += seq - last - 1
                self._last_seq[key] = seq

    def snapshot(self) -> tuple[dict[str, int], dict[str, int]]:
        with self.lock:
            return dict(self.counts), dict(self.gaps)

    def close(self) -> None:
        self._sub.undeclare()


def window(traffic: Traffic, router_pid: int, seconds: float) -> dict:
    """Rates per key, new sequence gaps per key, router CPU share and RSS over `seconds`."""
    counts0, gaps0 = traffic.snapshot()
    cpu0, t0 = cpu_seconds(router_pid), time.monotonic()
    time.sleep(seconds)
    counts1, gaps1 = traffic.snapshot()
    elapsed = time.monotonic() - t0
    return {"rates": {k: (n - counts0.get(k, 0)) / elapsed for k, n in counts1.items()},
            "gaps": {k: n - gaps0.get(k, 0) for k, n in gaps1.items() if n - gaps0.get(k, 0)},
            "cpu": (cpu_seconds(router_pid) - cpu0) / elapsed, "rss_mb": rss_mb(router_pid)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench fleet", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cars", type=int, default=5, help="simulated cars added (default 5)")
    parser.add_argument("--seconds", type=float, default=60.0, help="the fleet's window (default 60)")
    parser.add_argument("--baseline-seconds", type=float, default=10.0, help="the car alone (default 10)")
    args = parser.parse_args(argv)
    print(f"fleet benchmark: the sim profile's car, then {args.cars} more simulated cars on its router, "
          f"an observer on viena/**", flush=True)
    with tempfile.TemporaryDirectory(prefix="viena-bench-fleet-") as tmp, \
            sim_car("tcp", Path(tmp)) as (env, endpoint), open_as(env, endpoint, "observer") as session:
        traffic = Traffic(session)
        router = pids(env)["router"]
        try:
            _wait_for(traffic, [CAR + k for k in CAR_KEYS], 90)
            time.sleep(2.0)
            alone = window(traffic, router, args.baseline_seconds)
            with processes() as start:
                for n in range(1, args.cars + 1):
                    start("-m", "viena.services.sim.service", "--car", f"car{n}", "--connect", endpoint,
                          "--log-level", "WARNING")
                _wait_for(traffic, [f"viena/car{n}/sim/truth" for n in range(1, args.cars + 1)], 60)
                time.sleep(2.0)
                fleet = window(traffic, router, args.seconds)
        finally:
            traffic.close()
    report(args, alone, fleet)
    return 0


def _wait_for(traffic: Traffic, keys: list[str], timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        counts, _ = traffic.snapshot()
        if all(counts.get(k) for k in keys):
            return
        time.sleep(0.2)
    raise TimeoutError(f"nothing on {[k for k in keys if not traffic.snapshot()[0].get(k)]}")


def report(args, alone: dict, fleet: dict) -> None:
    print(f"the car's rates, alone ({args.baseline_seconds:.0f} s) and with {args.cars} more cars "
          f"({args.seconds:.0f} s):")
    for key in CAR_KEYS:
        a, f = alone["rates"].get(CAR + key, 0.0), fleet["rates"].get(CAR + key, 0.0)
        print(f"  {key:20s} {a:7.2f} Hz  {f:7.2f} Hz  {(f / a - 1) * 100 if a else float('nan'):+6.2f} %")
    health = [k for k in fleet["rates"] if k.startswith(CAR) and k.endswith("/health")]
    print(f"  health ({len(health)} services)  "
          f"{min(fleet['rates'][k] for k in health) if health else 0:.2f} Hz at the least")
    car_gaps = {k: n for k, n in fleet["gaps"].items() if k.startswith(CAR)}
    print(f"the car's sequence gaps with the fleet: {sum(car_gaps.values())} (goal 0) {car_gaps or ''}")
    truth = [fleet["rates"].get(f"viena/car{n}/sim/truth", 0.0) for n in range(1, args.cars + 1)]
    print(f"fleet cars' truth: {min(truth):.2f} .. {max(truth):.2f} Hz")
    per_car_cpu = (fleet["cpu"] - alone["cpu"]) / args.cars
    per_car_mb = (fleet["rss_mb"] - alone["rss_mb"]) / args.cars
    print(f"router CPU: alone {alone['cpu'] * 100:.1f} %, with the fleet {fleet['cpu'] * 100:.1f} % of a core; "
          f"{per_car_cpu * 100:+.2f} % per added car")
    print(f"router RSS: alone {alone['rss_mb']:.1f} MB, with the fleet {fleet['rss_mb']:.1f} MB; "
          f"{per_car_mb:+.2f} MB per added car")


if __name__ == "__main__":
    raise SystemExit(main())
