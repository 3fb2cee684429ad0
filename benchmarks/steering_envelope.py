"""Steering envelope benchmark: what one decision of the speed-aware envelope costs, and
the limits it keeps.

    viena bench steering_envelope       (or: python -m benchmarks.steering_envelope [--samples 100000])

The pure model (services/steering/model/safety.py) in this process, no zenoh, no drive.
Prints:

- per setpoint: parse + judge of a signed setpoint (`requests.parse_setpoint` and
  `Envelope.setpoint`: the code, the range, the speed, the lateral and rate limits), mean
  and p99 in microseconds (goal <= 100 us); and with the JSON decoding before it;
- per control tick (`Envelope.tick`) and per speed sample (`SpeedSources.estimator`);
- the allowed wheel angle and rate against speed, normal and engaging (the figures of
  docs/steering.md#the-speed-envelope).
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import time

from benchmarks.harness import percentile
from viena.services.steering.model.lateral import LateralSettings, lateral_accel_mps2, limits
from viena.services.steering.model.requests import parse_setpoint
from viena.services.steering.model.safety import ACCEPTED, CLAMPED, Envelope, SafetySettings
from viena.services.steering.model.signing import signed_setpoint

WALL_NS = 1_700_000_000_000_000_000
PERIOD = 0.01
SPEEDS_TABLE = (0, 2, 4, 6, 8, 10, 12, 14, 15)


def _us(values: list[float]) -> str:
    mean = sum(values) / len(values)
    return f"mean {mean * 1e6:6.1f} us   p99 {percentile(values, 99) * 1e6:6.1f} us   (n={len(values)})"


def _envelope(speed_mps: float) -> tuple[Envelope, str]:
    env = Envelope(SafetySettings(), LateralSettings())
    env.set_range(-29.0, 29.0)
    env.speeds.estimator(WALL_NS, speed_mps, 0.1, True, 0.0, WALL_NS)
    return env, env.arm(0.0, 0.0)


def _feed(env: Envelope, speed_mps: float, now: float) -> None:
    wall = WALL_NS + round(now * 1e9)
    env.speeds.estimator(wall, speed_mps, 0.1, True, now, wall)


def bench_setpoints(samples: int, decode: bool = False) -> tuple[list[float], int]:
    """Signed setpoints at 50 Hz (simulated time), a sweep past the lateral bound at 8 m/s so
    every limit has its turn, the estimator at 50 Hz; the drive follows the target. The time
    of parse + judge (with `decode`, of the JSON decoding before them too), and how many were
    clamped."""
    env, lease = _envelope(8.0)
    payloads = [signed_setpoint(lease, 20.0 * math.sin(k * 0.02), seq=k + 1) for k in range(samples)]
    wires: list = [json.dumps(p).encode() for p in payloads] if decode else payloads
    gc.freeze()                    # the prepared payloads are not the decision's garbage to scan
    times, clamped = [], 0
    now, measured = 0.0, 0.0
    clock = time.perf_counter
    for k, wire in enumerate(wires):
        now += 0.02
        _feed(env, 8.0, now)
        t0 = clock()
        d = env.setpoint(parse_setpoint(json.loads(wire) if decode else wire), measured, now, WALL_NS)
        times.append(clock() - t0)
        if d.status not in (ACCEPTED, CLAMPED) or d.target_deg is None:
            raise RuntimeError(f"setpoint {k} {d.status}: {d.reason}")
        clamped += d.status == CLAMPED
        measured = d.target_deg
    gc.unfreeze()
    return times, clamped


def bench_ticks(samples: int) -> list[float]:
    env, lease = _envelope(8.0)
    env.setpoint(parse_setpoint(signed_setpoint(lease, 25.0, seq=1)), 0.0, 0.0, WALL_NS)
    ticks, now, measured = [], 0.0, 0.0
    clock = time.perf_counter
    for k in range(samples):
        now += PERIOD
        if k % 40 == 39:                                   # keep the watchdog fed
            env.setpoint(parse_setpoint(signed_setpoint(lease, -25.0 if k % 80 == 79 else 25.0, seq=k + 2)),
                         measured, now, WALL_NS)
        t0 = clock()
        target, tripped = env.tick(measured, now)
        ticks.append(clock() - t0)
        if tripped or target is None:
            raise RuntimeError(f"tripped: {tripped}")
        measured = target
    return ticks


def bench_speed_samples(samples: int) -> tuple[list[float], list[float]]:
    """(a sample taken, a bad one refused)"""
    env, _lease = _envelope(8.0)
    taken, refused = [], []
    clock = time.perf_counter
    for k in range(samples):
        now = k * 0.02
        wall = WALL_NS + round(now * 1e9)
        t0 = clock()
        env.speeds.estimator(wall, 8.0, 0.1, True, now, wall)
        t1 = clock()
        env.speeds.gnss("gnss0", wall, math.nan, 0.1, True, now, wall)
        t2 = clock()
        taken.append(t1 - t0)
        refused.append(t2 - t1)
    return taken, refused


def print_table() -> None:
    s, slew = LateralSettings(), SafetySettings().slew_deg_s
    print(f"\nallowed wheel angle and rate against speed (wheelbase {s.wheelbase_m} m; lateral accel and jerk "
          f"scheduled {list(s.lateral_accel_mps2)} m/s^2, {list(s.lateral_jerk_mps3)} m/s^3 at "
          f"{list(s.lateral_speeds_mps)} m/s; engaging {s.engage_lateral_accel_mps2} m/s^2, "
          f"{s.engage_lateral_jerk_mps3} m/s^3 for {s.engage_s} s)")
    print("  speed |            normal                       |            engaging")
    print("    m/s |  a m/s^2  wheel deg  slew deg/s  rate@0 deg/s |  a m/s^2  wheel deg  rate@0 deg/s")
    for v in SPEEDS_TABLE:
        n, e = limits(v, s, slew), limits(v, s, slew, engaging=True)
        print(f"  {v:5.1f} | {n.lateral_accel_mps2:7.2f}  {_deg(n.max_wheel_deg)}  {n.slew_deg_s:10.1f}  "
              f"{_deg(n.rate_deg_s(0.0))}    | {e.lateral_accel_mps2:7.2f}  {_deg(e.max_wheel_deg)}  "
              f"{_deg(e.rate_deg_s(0.0))}")
    print("  (wheel: the widest angle, v^2 tan(wheel) / L = a; rate@0: the fastest turn from straight ahead, "
          "the slew or the jerk's rate; the range, +-28 deg, applies on top)")


def _deg(x: float) -> str:
    return f"{'open':>9}" if math.isinf(x) else f"{x:9.2f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench steering_envelope", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=100_000, help="decisions timed (default 100000)")
    args = parser.parse_args(argv)
    n = args.samples
    print("steering envelope benchmark (the pure model, one process)")
    judged, clamped = bench_setpoints(n)
    print(f"setpoint parse + judge           {_us(judged)}   goal <= 100 us; {clamped} clamped")
    print(f"setpoint json + parse + judge    {_us(bench_setpoints(n, decode=True)[0])}")
    print(f"control tick                     {_us(bench_ticks(n))}")
    taken, refused = bench_speed_samples(n)
    print(f"speed sample taken               {_us(taken)}")
    print(f"speed sample refused (NaN)       {_us(refused)}")
    print_table()
    at_14 = limits(14.0, LateralSettings(), SafetySettings().slew_deg_s)
    print(f"\nat 14 m/s: {at_14.max_wheel_deg:.2f} deg, "
          f"{lateral_accel_mps2(14.0, at_14.max_wheel_deg, at_14.wheelbase_m):.2f} m/s^2 "
          f"(25 deg would be {lateral_accel_mps2(14.0, 25.0, at_14.wheelbase_m):.1f} m/s^2)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
