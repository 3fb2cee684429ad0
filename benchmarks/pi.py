"""`viena bench pi`: the pi profile under a CPU budget like a Raspberry Pi 4's.

    viena bench pi [--seconds 120] [--cores 1.333] [--json]

Runs the `pi` profile itself (`viena up --profile pi`: its router with TLS and access
control, both GNSS services, the IMU service, the steering service, the estimator and
the black box), plus the Foxglove bridge, all in one cgroup with a CPU quota of
`--cores` cores (4 x 1/3 of a core here by default: benchmarks/cpu_quota.py). The devices
are their twins (viena-sim, outside the budget, on a router of its own so that its truth
stays off the car's dataflow), reached the way the real ones are: pyserial on the
receivers' and the IMU's ports, python-can's slcan on the steering's CAN adapter.

This process stands in for the laptop, outside the budget: it arms the steering and sends
signed setpoint queries at 50 Hz for the whole run (as the pilot does), subscribes to
every key, and keeps one Foxglove client subscribed to every channel. After a warm-up it
measures for `--seconds` and prints:

- every key's rate against its nominal rate (common/samples/topics.py) (goal >= 99 %);
- the setpoint round trip p50/p99 (goal p99 <= 10 ms) and the watchdog trips (goal 0);
- the estimator's lag: its state's time against when it arrived here, p50/p99;
- CPU (a share of one core here) and RSS per program, and all of them together as a share
  of the emulated Pi (goal <= 35 %; each program <= 60 MB RSS);
- the recorder's disk rate, and how often the quota held the group back.

`--json` prints the same as one JSON object instead.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.cpu_quota import CpuQuota
from benchmarks.harness import (
    cpu_seconds,
    free_port,
    memory_mb,
    percentile,
    processes,
    pss_mb,
    start_router,
    wait_for_port,
)
from benchmarks.security import open_as

CAR = "elettra"
VIENA = [sys.executable, "-m", "viena.cli"]
PI_CORES = 4 / 3                       # four Pi 4 cores, each about a third of one here
SETPOINT_HZ = 50.0
GOALS = {"rate_share": 0.99, "round_trip_p99_ms": 10.0, "watchdog_trips": 0, "pi_share": 0.35, "rss_mb": 60.0}
#: the twins' ports, as compose/sim.toml names them
TWIN_PORTS = ("VIENA_GNSS0_PORT", "VIENA_GNSS0_COM2_PORT", "VIENA_GNSS1_PORT", "VIENA_GNSS1_COM2_PORT",
              "VIENA_RAZOR0_PORT", "VIENA_EPOS_PORT")


# -- the car: twins outside the budget, the pi profile inside it --------------------------
def start_twins(start, ports: dict[str, int]) -> None:
    """viena-sim with its device twins on `ports`, publishing its truth to a router of its own."""
    from viena.common.paths import compose_dir

    router = start_router(start)
    start("-m", "viena.services.sim.service", "--connect", router, "--config", compose_dir() / "sim.toml",
          "--log-level", "WARNING", env=dict(os.environ, **{name: str(port) for name, port in ports.items()}))
    for name, port in ports.items():
        if "COM2" not in name:                     # (a receiver's COM2 listens only with --rtk)
            wait_for_port(port, 30.0)


def pi_environment(work: Path, ports: dict[str, int]) -> dict[str, str]:
    """What `viena up --profile pi` is given: a key store, run and drive directories of this
    run, and the devices at the twins' ports."""
    env = dict(os.environ, VIENA_RUN=str(work / "run"), VIENA_KEYS=str(work / "keys"),
               VIENA_DRIVES=str(work / "drives"), VIENA_ROUTER_HOST="127.0.0.1",
               VIENA_GNSS0_DEVICE=f"socket://127.0.0.1:{ports['VIENA_GNSS0_PORT']}",
               VIENA_GNSS1_DEVICE=f"socket://127.0.0.1:{ports['VIENA_GNSS1_PORT']}",
               VIENA_RAZOR0_DEVICE=f"socket://127.0.0.1:{ports['VIENA_RAZOR0_PORT']}",
               VIENA_CAN_INTERFACE="slcan", VIENA_CAN_CHANNEL=f"socket://127.0.0.1:{ports['VIENA_EPOS_PORT']}")
    for name in ("VIENA_ROUTER_PORT", "VIENA_LINK", "VIENA_IDENTITY", "VIENA_RECORD", *TWIN_PORTS):
        env.pop(name, None)
    return env


def pi_up(env: dict[str, str], quota: CpuQuota) -> str:
    """The pi profile up inside the quota's group; the router's endpoint."""
    from viena.keys_cli import main as keys_main

    with contextlib.redirect_stdout(io.StringIO()):
        keys_main(["--keys", env["VIENA_KEYS"], "init"])
    up = subprocess.run([*VIENA, "up", "-d", "--profile", "pi", "--free-ports"], env=env, capture_output=True,
                        text=True, timeout=180, preexec_fn=quota.join)
    if up.returncode != 0:
        raise RuntimeError(f"viena up --profile pi failed: {up.stderr}")
    saved = json.loads((Path(env["VIENA_RUN"]) / "env.json").read_text())
    return f"tls/localhost:{saved['VIENA_ROUTER_PORT']}"


def pi_down(env: dict[str, str]) -> None:
    subprocess.run([*VIENA, "down", "--profile", "pi"], env=env, capture_output=True, timeout=60)


# -- what this process measures -----------------------------------------------------------
class Watch:
    """Every sample of the car: arrivals per key, the estimator's lag, the watchdog's trips."""

    def __init__(self, session):
        from viena.common.keys import Keys
        from viena.common.samples import topics as T

        keys = Keys(CAR)
        self.prefix = keys.of(T.SIM_TRUTH).rsplit("/", 2)[0] + "/"
        self.estimator_key, self.steering_key = keys.of(T.ESTIMATOR_STATE), keys.of(T.STEERING_STATE)
        self.lock = threading.Lock()
        self.arrivals: dict[str, list[float]] = {}
        self.lags: list[tuple[float, float]] = []        # (arrival, lag s)
        self.trips: list[tuple[float, str]] = []         # (arrival, the state's trip text)
        self._tripped = False
        self._sub = session.declare_subscriber(self.prefix + "**", self._on)

    def _on(self, sample) -> None:
        from viena.common.schema import unpack

        now, wall_ns, key = time.monotonic(), time.time_ns(), str(sample.key_expr)
        with self.lock:
            self.arrivals.setdefault(key, []).append(now)
        if key not in (self.estimator_key, self.steering_key):
            return
        value = unpack(sample.payload.to_bytes())
        with self.lock:
            if key == self.estimator_key:
                self.lags.append((now, (wall_ns - value["t"]) / 1e9))
            else:
                tripped = value.get("watchdog") == "tripped"
                if tripped and not self._tripped:
                    self.trips.append((now, value.get("trip", "")))
                self._tripped = tripped

    def rates(self, t0: float, t1: float) -> dict[str, dict]:
        from viena.common.samples.topics import topic_of_key

        out = {}
        with self.lock:
            inside = {key: [t for t in times if t0 <= t < t1] for key, times in self.arrivals.items()}
        for key in sorted(inside):
            found = topic_of_key(key)
            nominal = found[0].nominal_hz if found else None
            measured = _rate(inside[key], t1 - t0)
            out[key[len(self.prefix):]] = {"nominal_hz": nominal, "measured_hz": round(measured, 3),
                                           "share": round(measured / nominal, 4) if nominal else None}
        return out

    def close(self) -> None:
        self._sub.undeclare()


def _rate(times: list[float], window_s: float) -> float:
    """Samples a second: the mean interval between the first and the last in the window, so
    that where the window's edges fall does not count (a 1 Hz key has 59 or 60 samples in
    60 s by its phase alone); a sample missing between them still lengthens it."""
    if len(times) < 2:
        return len(times) / window_s
    return (len(times) - 1) / (times[-1] - times[0])


class Setpoints:
    """The pilot's part, through the pilot's own SteeringClient (which keeps the router's
    spacing between queries): armed, a signed setpoint query every 1/50 s (a slow 2 degree
    sine), each reply's round trip kept; a refusal because the steering stopped is counted
    and the steering armed again."""

    def __init__(self, session):
        from viena.services.steering.client import SteeringClient

        self.client = SteeringClient(session, CAR, timeout_s=1.0, name="bench")
        self.lock = threading.Lock()
        self.round_trips: list[tuple[float, float]] = []   # (sent, s)
        self.refused: list[tuple[float, str]] = []
        self.unanswered = 0
        self.errors: list[str] = []                      # the first error replies, as said
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoints", daemon=True)

    def wait_calibrated(self, timeout: float = 120.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.client.ask("calibration", {}).get("calibration", {}).get("state") == "done":
                return
            time.sleep(0.5)
        raise TimeoutError("the steering did not calibrate")

    def arm(self) -> None:
        reply: dict = {}
        for _ in range(20):
            reply = self.client.arm()
            if reply.get("status") == "accepted":
                return
            time.sleep(0.5)
        raise RuntimeError(f"arm refused: {reply}")

    def start(self) -> Setpoints:
        self.arm()
        self._thread.start()
        return self

    def _run(self) -> None:
        period, t_start = 1.0 / SETPOINT_HZ, time.monotonic()
        next_at = t_start
        while not self._stop.is_set():
            now = time.monotonic()
            t0 = time.perf_counter()
            reply = self.client.setpoint(2.0 * math.sin(2 * math.pi * 0.1 * (now - t_start)))
            t1 = time.perf_counter()
            reason = str(reply.get("reason", ""))
            with self.lock:
                if reason.startswith("no answer"):
                    self.unanswered += 1
                    self.errors.append(reason)
                elif reply.get("status") == "rejected":
                    self.refused.append((now, reason))
                else:
                    self.round_trips.append((now, t1 - t0))
            if reply.get("status") == "rejected" and "arm" in reason:
                try:
                    self.arm()
                except RuntimeError as exc:                 # said in the report; asked again next period
                    self.errors.append(str(exc))
            next_at += period                               # on schedule, as the pilot's; no burst
            if time.monotonic() - next_at > period:
                next_at = time.monotonic()
            self._stop.wait(next_at - time.monotonic())

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.client.disarm()


# -- the programs' CPU and memory ---------------------------------------------------------
def process_cpu(pid: int) -> float | None:
    """CPU seconds of a process (its threads included); None once it is gone."""
    try:
        return cpu_seconds(pid)
    except (FileNotFoundError, ProcessLookupError):
        return None


def directory_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


# -- the run --------------------------------------------------------------------------------
def run(seconds: float, cores: float, warmup: float, as_json: bool) -> int:
    say = (lambda *a: print(*a, file=sys.stderr, flush=True)) if as_json else (lambda *a: print(*a, flush=True))
    quota = CpuQuota(cores, f"viena-bench-pi-{os.getpid()}")
    if not quota.active:
        say(f"viena bench pi: {quota.why_not}")
    try:
        with tempfile.TemporaryDirectory(prefix="viena-bench-pi-") as tmp, processes() as start:
            work = Path(tmp)
            ports = {name: free_port() for name in TWIN_PORTS}
            start_twins(start, ports)
            env = pi_environment(work, ports)
            try:
                say(f"the pi profile up under {cores:.2f} cores of quota, the twins outside it ...")
                endpoint = pi_up(env, quota)
                fox_port = free_port()
                fox = start("-m", "viena.cli", "foxglove", "--port", fox_port, "--host", "127.0.0.1", "--connect",
                            endpoint, "--keys", env["VIENA_KEYS"], "--identity", "observer", "--car", CAR,
                            "--log-level", "WARNING", preexec_fn=quota.join)
                wait_for_port(fox_port, 30.0)
                with open_as(env, endpoint, "pilot") as session:
                    report = measure(session, env, quota, fox.pid, fox_port, seconds, warmup, say)
            finally:
                pi_down(env)
    finally:
        quota.remove()                                   # and whatever of the group outlived the rest
    report["cores"], report["quota"] = cores, quota.active
    if as_json:
        print(json.dumps(report, indent=1))
    else:
        print_report(report)
    return 0


def measure(session, env, quota: CpuQuota, fox_pid: int, fox_port: int, seconds: float, warmup: float,
            say) -> dict:
    from benchmarks.faults import pids as program_pids
    from benchmarks.foxglove import Reader

    watch = Watch(session)
    client = Reader(fox_port)
    setpoints = Setpoints(session)
    try:
        say("waiting for the steering's calibration ...")
        setpoints.wait_calibrated()
        setpoints.start()
        time.sleep(warmup)
        with watch.lock:
            heard = set(watch.arrivals)
        client.subscribe_when(heard)                    # one client on every channel
        programs = {name: pid for name, pid in program_pids(env).items() if pid}
        programs["foxglove"] = fox_pid
        say(f"measuring {seconds:.0f} s: {', '.join(programs)}")
        throttled0 = quota.throttling()
        drives = Path(env["VIENA_DRIVES"])
        c0 = {name: process_cpu(pid) for name, pid in programs.items()}
        b0, t0 = directory_bytes(drives), time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        c1 = {name: process_cpu(pid) for name, pid in programs.items()}
        b1, throttled1 = directory_bytes(drives), quota.throttling()
        memory = {name: rss for name, pid in programs.items() if (rss := memory_mb(pid)) is not None}
        shared = {name: pss_mb(pid) for name, pid in programs.items()}
    finally:
        setpoints.stop()
        client.close()
        watch.close()
    span = t1 - t0
    cpu = {name: (after - before) / span for name, before, after in ((n, c0[n], c1[n]) for n in programs)
           if before is not None and after is not None and name in memory}   # died meanwhile: left out, said

    with setpoints.lock:
        trips_ms = [rt * 1e3 for sent, rt in setpoints.round_trips if t0 <= sent < t1]
        refused = [reason for sent, reason in setpoints.refused if t0 <= sent < t1]
    with watch.lock:
        lags = [lag * 1e3 for at, lag in watch.lags if t0 <= at < t1]
        trips = [text for at, text in watch.trips if t0 <= at < t1]
    total = sum(cpu.values())
    return {
        "seconds": round(span, 1),
        "rates": watch.rates(t0, t1),
        "setpoint_round_trip_ms": {"p50": round(percentile(trips_ms, 50), 2), "p99": round(percentile(trips_ms, 99), 2),
                                   "n": len(trips_ms), "refused": len(refused), "unanswered": setpoints.unanswered},
        "watchdog_trips": len(trips), "trips": trips[:5], "setpoint_errors": sorted(set(setpoints.errors))[:5],
        "estimator_lag_ms": {"p50": round(percentile(lags, 50), 1), "p99": round(percentile(lags, 99), 1)},
        "programs": {name: {"cpu_core_share": round(cpu[name], 4), "rss_mb": round(memory[name][0], 1),
                            "peak_rss_mb": round(memory[name][1], 1),
                            "pss_mb": round(shared[name] or 0.0, 1)} for name in cpu},
        "programs_gone": sorted(set(programs) - set(cpu)),
        "total_cpu_core_share": round(total, 4),
        "total_pi_share": round(total / PI_CORES, 4),
        "recorder_mb_per_h": round((b1 - b0) / span * 3600 / 1e6, 1),
        "throttling": {k: throttled1[k] - throttled0.get(k, 0) for k in throttled1},
        "foxglove_frames": len(client.frames),
    }


def print_report(r: dict) -> None:
    quota = f"{r['cores']:.2f} cores of quota" if r["quota"] else "no quota"
    print(f"viena bench pi: the pi profile + Foxglove bridge, {quota}, {r['seconds']:.0f} s at 50 Hz setpoints")
    print(f"\n{'key':44s} {'nominal':>8s} {'measured':>9s} {'share':>7s}")
    held = True
    for key, rate in r["rates"].items():
        nominal = f"{rate['nominal_hz']:g}" if rate["nominal_hz"] else "-"
        share = f"{100 * rate['share']:6.1f}%" if rate["share"] is not None else "      -"
        if rate["share"] is not None and rate["nominal_hz"] >= 1 and rate["share"] < GOALS["rate_share"]:
            held, share = False, share + " <"
        print(f"{key:44s} {nominal:>8s} {rate['measured_hz']:9.2f} {share}")
    print(f"every rate held (>= {100 * GOALS['rate_share']:g} % of nominal): {'yes' if held else 'no'}")
    rt = r["setpoint_round_trip_ms"]
    print(f"\nsetpoint round trip   p50 {rt['p50']:6.2f} ms  p99 {rt['p99']:6.2f} ms  "
          f"(goal p99 <= {GOALS['round_trip_p99_ms']:g}; n={rt['n']}, refused {rt['refused']}, "
          f"unanswered {rt['unanswered']})")
    if r["setpoint_errors"]:
        print(f"                      error replies or none: {'; '.join(r['setpoint_errors'])}")
    print(f"watchdog trips        {r['watchdog_trips']}   (goal {GOALS['watchdog_trips']})"
          + (f": {r['trips']}" if r["trips"] else ""))
    lag = r["estimator_lag_ms"]
    print(f"estimator lag         p50 {lag['p50']:6.1f} ms  p99 {lag['p99']:6.1f} ms  (its state's time to here)")
    print(f"\n{'program':12s} {'CPU % core':>10s} {'RSS MB':>7s} {'peak':>6s} {'PSS MB':>7s}")
    for name, p in sorted(r["programs"].items(), key=lambda item: -item[1]["cpu_core_share"]):
        flag = f"  > {GOALS['rss_mb']:g} MB" if p["rss_mb"] > GOALS["rss_mb"] else ""
        print(f"{name:12s} {100 * p['cpu_core_share']:10.1f} {p['rss_mb']:7.1f} {p['peak_rss_mb']:6.1f} "
              f"{p['pss_mb']:7.1f}{flag}")
    if r["programs_gone"]:
        print(f"{'gone':12s} {', '.join(r['programs_gone'])} (died while measured)")
    print(f"{'together':12s} {100 * r['total_cpu_core_share']:10.1f}   = {100 * r['total_pi_share']:.1f} % of the "
          f"emulated Pi (4 x 1/3 core; goal <= {100 * GOALS['pi_share']:g} %)")
    th = r["throttling"]
    if th:
        print(f"quota held the group back in {th['throttled_periods']} of {th['periods']} periods "
              f"({th['throttled_s']:.2f} s in all)")
    print(f"recorder              {r['recorder_mb_per_h']:.1f} MB/h to disk; Foxglove client got "
          f"{r['foxglove_frames']} frames")


def main(argv: list[str] | None = None) -> int:
    """`viena bench pi [--seconds S] [--cores C] [--json]`: see the module's docstring."""
    p = argparse.ArgumentParser(prog="viena bench pi", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=120.0, help="how long to measure (after the warm-up)")
    p.add_argument("--warmup", type=float, default=10.0, help="seconds of setpoints before measuring")
    p.add_argument("--cores", type=float, default=PI_CORES, help="the CPU quota, in cores of this machine")
    p.add_argument("--json", dest="as_json", action="store_true", help="print one JSON object")
    return run(**vars(p.parse_args(argv)))


if __name__ == "__main__":
    raise SystemExit(main())
