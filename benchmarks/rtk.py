"""RTK benchmark: the whole corrections chain on the sim car, and what it buys the pilot.

    viena bench rtk            (or: python -m benchmarks.rtk [--baseline-m 1000] [--speed 5])

`viena up --rtk` on free ports (the caster's twin serving RTCM 3 from a base station
`--baseline-m` from the sim's origin, viena-ntrip, both receivers taking the corrections),
then, printing each figure:

1. the solution types: how long from the first corrections until each receiver is
   differential, float and fixed (the twin's convergence);
2. the correction age at the receivers: from the caster's send (the observables' epoch,
   which the twin sends as it makes them) to the receiver twin's read, p50/p95/max (the
   sim's health carries the twin's own count), and the receivers' diff age in the fixes;
3. the pilot once round the loop at `--speed` through the estimator, fixed RTK:
   cross-track against the truth RMS / worst (goal <= 0.15 m RMS, <= 0.30 m worst);
4. a caster restart (stopped `--restart-down-s`, started again): how long until
   corrections flow again (goal <= 15 s), and the client's connection attempts (never two
   less than 10 s apart);
5. corrections stopped for good while the pilot follows a second time: when its precision
   rule stops it (`min_solution float`, `max_diff_age_s` 5 s), and how long until each
   receiver's fixes fall back (the OEM4: fixed held 30 s, the RTK timeout 60 s).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

KINDS_WANTED = ("dgps", "float", "fixed")
#: what a receiver falls back to without corrections (the sim's twins have SBAS on)
FALLBACK = ("single", "sbas")


class Watch:
    """What the bus says, with the wall time it was heard: fixes, corrections, the client's
    state and the sim's health."""

    def __init__(self, session, car: str = "elettra"):
        from viena.common.samples.fix import solution_kind
        from viena.common.samples.health import HEALTH
        from viena.common.schema import unpack

        self._unpack, self._kind, self._health = unpack, solution_kind, HEALTH
        self.lock = threading.Lock()
        self.fixes: dict[str, list[tuple[float, str, float | None]]] = {}   # unit -> (heard, kind, diff age)
        self.corrections: list[tuple[float, int]] = []                     # (heard, bytes)
        self.ntrip: list[tuple[float, dict]] = []
        self.sim_health: dict = {}
        root = f"viena/{car}"
        self._subs = [session.declare_subscriber(f"{root}/gnss/*/fix", self._on_fix),
                      session.declare_subscriber(f"{root}/gnss/corrections", self._on_corrections),
                      session.declare_subscriber(f"{root}/ntrip/state", self._on_ntrip),
                      session.declare_subscriber(f"{root}/sim/health", self._on_sim_health)]

    def _on_fix(self, sample) -> None:
        fix = self._unpack(sample.payload.to_bytes())
        kind = self._kind(fix.get("pos_type")) if fix.get("valid") else "none"
        with self.lock:
            self.fixes.setdefault(fix["unit"], []).append((time.monotonic(), kind, fix.get("diff_age_s")))

    def _on_corrections(self, sample) -> None:
        data = self._unpack(sample.payload.to_bytes())
        with self.lock:
            self.corrections.append((time.monotonic(), len(data.get("data") or b"")))

    def _on_ntrip(self, sample) -> None:
        with self.lock:
            self.ntrip.append((time.monotonic(), self._unpack(sample.payload.to_bytes())))

    def _on_sim_health(self, sample) -> None:
        with self.lock:
            self.sim_health = self._health.decode(sample.payload.to_bytes())

    def first(self, unit: str, kind: str | tuple[str, ...], after: float = 0.0) -> float | None:
        kinds = (kind,) if isinstance(kind, str) else kind
        with self.lock:
            return next((t for t, k, _ in self.fixes.get(unit, []) if t >= after and k in kinds), None)

    def kinds_now(self) -> dict[str, str]:
        with self.lock:
            return {u: f[-1][1] for u, f in self.fixes.items() if f}

    def wait(self, what, timeout_s: float, step_s: float = 0.2):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            got = what()
            if got:
                return got
            time.sleep(step_s)
        return None

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def run(baseline_m: float, speed_mps: float, restart_down_s: float, fix_timeout_s: float,
        controller: str = "stanley") -> int:
    import zenoh

    from benchmarks.faults import supervisor
    from benchmarks.harness import processes
    from benchmarks.pilot import LiveLoop
    from benchmarks.security import sim_car
    from viena.common.config import load_zenoh_config

    os.environ["VIENA_SIM_SPEED_MIN_MPS"] = os.environ["VIENA_SIM_SPEED_MAX_MPS"] = str(speed_mps)
    os.environ["VIENA_RTK_BASELINE_M"] = str(baseline_m)
    os.environ.pop("VIENA_SIM_GNSS_CEP_M", None)
    with tempfile.TemporaryDirectory(prefix="viena-bench-rtk-") as tmp, \
            sim_car("tcp", Path(tmp), flags=("--rtk",)) as (env, endpoint), processes() as start:
        session = zenoh.open(load_zenoh_config(mode="client", connect=[endpoint]))
        watch = Watch(session)
        sup = supervisor(env)
        try:
            t0 = time.monotonic()
            print(f"rtk: `viena up --rtk` on the sim car, base {baseline_m:g} m away, the person driving "
                  f"{speed_mps:g} m/s", flush=True)
            # 1. the solution types
            first_corr = watch.wait(lambda: watch.corrections and watch.corrections[0][0], 60.0)
            if first_corr is None:
                print("  no corrections came within 60 s: the chain is broken", flush=True)
                return 1
            print(f"  first corrections on gnss/corrections {first_corr - t0:.1f} s after the profile was up")
            fixed = watch.wait(lambda: all(k == "fixed" for k in watch.kinds_now().values())
                               and len(watch.kinds_now()) >= 2, fix_timeout_s)
            for unit in sorted(watch.fixes):
                times = {k: watch.first(unit, k, first_corr) for k in KINDS_WANTED}
                print(f"  {unit}: " + ", ".join(f"{k} after {t - first_corr:.1f} s" if t else f"{k} never"
                                                for k, t in times.items()))
            if not fixed:
                print(f"  not every receiver fixed within {fix_timeout_s:g} s: {watch.kinds_now()}", flush=True)
            # 2. the correction age
            ages = [a for f in watch.fixes.values() for _, k, a in f[-400:] if k != "single" and a is not None]
            if ages:
                print(f"  diff age in the fixes: p50 {np.percentile(ages, 50):.2f} s, p95 "
                      f"{np.percentile(ages, 95):.2f} s, max {max(ages):.2f} s (n={len(ages)})")
            twin = _twin_ages(watch.sim_health)
            if twin:
                print(f"  caster send -> receiver twin read: {twin}")
            # 3. the pilot
            sup.stopProcess("pilot")        # the profile's own (idle) pilot makes way
            start("-m", "viena.services.pilot.service", "--connect", endpoint, "--setpoint-rate-hz", "50",
                  "--max-estimate-age-s", "1.0", "--controller", controller, "--min-solution", "float", env=env)
            loop = LiveLoop(session)
            try:
                drive = loop.drive()
            finally:
                loop.close()
            errors = np.abs(drive.cross_track_m)
            worst_at = int(np.argmax(errors)) if len(errors) else 0
            print(f"  pilot ({controller}, min_solution float) round the loop at {speed_mps:g} m/s on RTK: "
                  f"{drive.mode} ({drive.reason}) in {drive.seconds:.1f} s; cross-track against the truth "
                  f"{drive.figures()} (goal RMS <= 0.15 m, worst <= 0.30 m); the worst at truth "
                  f"{worst_at} of {len(errors)}; kinds at the end {watch.kinds_now()}", flush=True)
            # 4. a caster restart
            sup.stopProcess("caster")
            stopped = time.monotonic()
            time.sleep(restart_down_s)
            sup.startProcess("caster")
            started = time.monotonic()
            back = watch.wait(lambda: next((t for t, _ in watch.corrections if t > started), None), 60.0)
            attempts = _attempt_times(watch, stopped)
            gaps = np.diff(attempts) if len(attempts) > 1 else np.array([])
            print(f"  caster down {restart_down_s:g} s: corrections again "
                  + (f"{back - started:.1f} s after it was back (goal <= 15 s)" if back else "never (60 s)")
                  + f"; connection attempts {len(attempts)}, closest two "
                  + (f"{gaps.min():.1f} s apart" if len(gaps) else "-") + " (never < 10 s)", flush=True)
            # 5. corrections gone for good, while the pilot follows
            watch.wait(lambda: all(k == "fixed" for k in watch.kinds_now().values()), fix_timeout_s)
            stop_at: list[float] = []

            def cut_corrections(t_s: float) -> None:
                if t_s >= 5.0 and not stop_at:
                    stop_at.append(time.monotonic())
                    sup.stopProcess("caster")
            loop = LiveLoop(session)
            try:
                drive = loop.drive(during=cut_corrections)
            finally:
                loop.close()
            last = max(t for t, _ in watch.corrections)
            print(f"  the caster stopped {5.0:g} s into a second drive: the pilot {drive.mode} "
                  f"({drive.reason}) {time.monotonic() - last:.1f} s after the last corrections "
                  f"(min_solution float, max_diff_age_s 5 s, held 1 s); cross-track until then "
                  f"{drive.figures()}", flush=True)
            units = sorted(watch.fixes)
            fallen = watch.wait(lambda: (all(watch.first(u, FALLBACK, last) for u in units)
                                         and [watch.first(u, FALLBACK, last) for u in units]), 120.0)
            floats = [watch.first(u, ("float", "dgps"), last) for u in units]
            if fallen:
                print("  corrections stopped: " + ", ".join(
                    f"{u} float after {f - last:.1f} s, {watch.kinds_now().get(u)} after {t - last:.1f} s"
                    for u, f, t in zip(units, [f or last for f in floats], fallen))
                    + " (the OEM4: fixed held 30 s, the RTK timeout 60 s)", flush=True)
            else:
                print(f"  corrections stopped: not back to {'/'.join(FALLBACK)} after 120 s: {watch.kinds_now()}")
        finally:
            watch.close()
            session.close()
    return 0


def _twin_ages(health: dict) -> str | None:
    """The receiver twins' own figures of correction age, from the sim's health."""
    state = (health or {}).get("state") or {}
    out = []
    for unit, figures in sorted(state.items()):
        if isinstance(figures, dict) and "correction_age_p95_s" in figures:
            out.append(f"{unit} p50 {figures.get('correction_age_p50_s', float('nan')):.2f} s, "
                       f"p95 {figures['correction_age_p95_s']:.2f} s (goal < 2 s)")
    return "; ".join(out) or None


def _attempt_times(watch: Watch, since: float) -> list[float]:
    """When the client began each connection attempt since `since`: its state is published
    at every change, so the state whose `attempts` went up was heard as the attempt began."""
    with watch.lock:
        states = list(watch.ntrip)
    times, seen = [], None
    for heard, state in states:
        n = state.get("attempts")
        if seen is not None and n is not None and n > seen and heard >= since:
            times.append(heard)
        seen = n if n is not None else seen
    return times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="viena bench rtk", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline-m", type=float, default=1000.0, help="the base station's distance (m)")
    p.add_argument("--speed", type=float, default=5.0, help="the sim person's speed (m/s)")
    p.add_argument("--restart-down-s", type=float, default=3.0, help="how long the caster stays down")
    p.add_argument("--fix-timeout-s", type=float, default=240.0, help="longest wait for both to fix")
    p.add_argument("--controller", default="stanley", choices=("stanley", "pure_pursuit"),
                   help="the pilot's tracker (stanley: the tighter at 5 m/s, docs/pilot.md#accuracy)")
    args = p.parse_args(argv)
    return run(args.baseline_m, args.speed, args.restart_down_s, args.fix_timeout_s, args.controller)


if __name__ == "__main__":
    raise SystemExit(main())
