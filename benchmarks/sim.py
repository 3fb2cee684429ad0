"""`viena bench sim`: the foundation's figures.

- msgpack encode + decode of one truth sample, with its schema checks (goal <= 20 us);
- the simulated car's CPU share at 100 Hz (goal < 10 % of one core);
- the truth rate a subscriber sees (goal 100 Hz +- 1 %).
"""
from __future__ import annotations

import argparse
import time

from benchmarks.harness import cpu_share, processes, start_router
from viena.common.config import load_zenoh_config
from viena.common.samples.truth import TRUTH
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import truth_sample


def codec_us(n: int = 20000) -> float:
    car = SimCar()
    sample = truth_sample(car.step(0.01))
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n // 5):
            TRUTH.decode(TRUTH.encode(sample))
        best = min(best, (time.perf_counter() - t0) / (n // 5))
    return best * 1e6


def live(seconds: float) -> tuple[float, float, int]:
    import zenoh

    with processes() as start:
        router = start_router(start)
        sim = start("-m", "viena.services.sim.service", "--connect", router, "--log-level", "WARNING")
        count = 0
        first = last = None

        def on_sample(_s):
            nonlocal count, first, last
            now = time.monotonic()
            first = first or now
            last = now
            count += 1
        with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
            sub = session.declare_subscriber("viena/elettra/sim/truth", on_sample)
            while first is None:
                time.sleep(0.05)
            time.sleep(1.0)                                    # past start-up
            count, first = 0, None
            share = cpu_share(sim.pid, seconds)
            n, span = count, (last - first) if first and last else 0.0
            sub.undeclare()
    rate = (n - 1) / span if span > 0 else 0.0
    return share, rate, n


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench sim", description=__doc__)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args(argv)
    print(f"truth msgpack encode+decode (checked): {codec_us():.1f} us/sample  (goal <= 20)")
    share, rate, n = live(args.seconds)
    print(f"simulated car CPU at 100 Hz:           {share * 100:.1f} % of one core  (goal < 10)")
    print(f"truth rate at a subscriber:            {rate:.2f} Hz over {n} samples  (goal 100 +- 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
