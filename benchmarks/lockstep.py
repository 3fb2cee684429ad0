"""`viena bench lockstep`: how fast the car runs in lockstep (viena.lockstep_car), on one core.

    python -m benchmarks.lockstep [--seconds S] [--drive | --idle] [--cpu N|none] [--seed N]

Prints, for the sim profile standing idle for S virtual seconds (after its start-up) and
for one closed-loop drive round the loop (the pilot through the estimator, RTK-grade
receivers, as benchmarks/pilot.py's live drive): the virtual seconds run, the CPU seconds
they took (`time.process_time()`: every thread of the process, so a loaded machine does
not count), the speed as a multiple of real time, the CPU milliseconds per virtual second,
the simulated threads' switches per virtual second, and what a 10-minute drive would cost
at that rate (goal: <= 30 s of CPU, >= 20x real time; issue 27).

By default the process is pinned to one CPU (`--cpu`: one no other simulation holds): the
goal is one core's, and the runner's threads hand the baton to each other well over a
thousand times a virtual second, which costs two to five times as much when a handoff may
cross cores (common/lockstep/scheduler.py).
"""
from __future__ import annotations

import argparse
import logging
import os
import time

#: the 10-minute drive of issue 27's goal, in virtual seconds, and its CPU budget
DRIVE_S, BUDGET_CPU_S = 600.0, 30.0
#: the receivers' error of the live drive (RTK-grade, as benchmarks/pilot.py's second run)
RTK_CEP_M = 0.05
_claim = None       # the lock file that holds this benchmark's CPU


def pin(cpu: str) -> str:
    """Pin this process (its threads to come) to one CPU, by default one that no simulation
    on this machine holds (as `VirtualClock(cpu="auto")` takes one); says which."""
    from viena.common.lockstep.scheduler import claim_cpu

    if cpu == "none" or not hasattr(os, "sched_setaffinity"):
        return "not pinned"
    global _claim
    if cpu == "auto":
        chosen, _claim = claim_cpu()               # held until this process ends
    else:
        chosen = int(cpu)
    if chosen is None:
        return "not pinned (every CPU is held by a simulation)"
    os.sched_setaffinity(0, {chosen})
    return f"pinned to CPU {chosen}"


def report(what: str, virtual_s: float, cpu_s: float, switches: int) -> None:
    ms = 1000 * cpu_s / virtual_s
    print(f"{what:<6} {virtual_s:7.1f} virtual s in {cpu_s:6.2f} CPU s: {virtual_s / cpu_s:5.1f}x real time, "
          f"{ms:5.1f} ms CPU per virtual s, {switches / virtual_s:5.0f} switches per virtual s; "
          f"a 10-minute drive: {DRIVE_S * ms / 1000:5.1f} CPU s (goal <= {BUDGET_CPU_S:.0f})")


def idle(seconds: float, seed: int) -> None:
    from viena.lockstep_car import LockstepCar

    c0 = time.process_time()
    with LockstepCar(seed=seed) as car:
        car.run_for(3.0)                                 # past the programs' start
        start_cpu_s = time.process_time() - c0
        c0, n0, v0 = time.process_time(), car.clock.switches, car.now_s
        car.run_for(seconds)
        report("idle", car.now_s - v0, time.process_time() - c0, car.clock.switches - n0)
    print(f"       (building and starting the car, with its first 3 virtual s: {start_cpu_s:.2f} CPU s)")


def drive(seed: int) -> None:
    from benchmarks.pilot import LiveLoop
    from viena.lockstep_car import LockstepCar

    receivers = {"cep_m": RTK_CEP_M}
    with LockstepCar(seed=seed, overrides={"sim": {"gnss0": receivers, "gnss1": receivers}}) as car:
        c0, n0, v0 = time.process_time(), car.clock.switches, car.now_s
        result = LiveLoop(car.session("bench")).drive()
        report("drive", car.now_s - v0, time.process_time() - c0, car.clock.switches - n0)
    print(f"       (the pilot {result.mode} after {result.seconds:.0f} virtual s; cross-track {result.figures()})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench lockstep", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="virtual seconds of the idle profile")
    only = parser.add_mutually_exclusive_group()
    only.add_argument("--drive", action="store_true", help="only the pilot's drive")
    only.add_argument("--idle", action="store_true", help="only the idle profile")
    parser.add_argument("--cpu", default="auto", help="the CPU to pin to, or none (default: one no simulation holds)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    print(f"lockstep car, {pin(args.cpu)}")
    if not args.drive:
        idle(args.seconds, args.seed)
    if not args.idle:
        drive(args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
