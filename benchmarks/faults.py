"""`viena bench faults`: what killed programs, floods and bad input cost the car (issue 15).

    viena bench faults [--samples 200] [--flood-rate 10000] [--pi-seconds 20]

1. Restart to flowing: on the sim profile, each program killed (SIGKILL) in turn;
   supervisord's restart (a new pid RUNNING) and the first sample on the program's own
   key after the kill (the router: the first truth sample through it).
2. The owner's setpoints under a flood: router, EPOS twin and `viena-steering` as
   processes (as `viena bench steering`); the owner's setpoint round trip p50/p99 at
   20 Hz, alone and while two other processes put setpoints with a foreign lease at
   --flood-rate each (goal: p99 within 2x of alone, no watchdog trip).
3. Bad input: the RSS of every program of the sim profile before and after the table of
   bad inputs (huge, deep, malformed and absurd commands and samples; discovery queries),
   3 s after the last (goal: +10 MB at most each).
4. A Pi-sized budget: the pi profile's programs (router, GNSS x2, IMU, steering,
   estimator) pinned with taskset to core 0 next to a busy loop on that core; the
   simulated car (the hardware) and this process on core 1; an owner armed and steering
   at 20 Hz. Rates of steering state (50 Hz), every health (1 Hz), the drive's heartbeat,
   watchdog trips and rejected setpoints, and each service's CPU share of core 0.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import xmlrpc.client
from collections import Counter
from pathlib import Path

import msgpack

from benchmarks.harness import (
    CLOCK_TICKS,
    cpu_seconds,
    percentile,
    processes,
    rss_mb,
    start_drive_twin,
    start_router,
    start_steering,
)
from benchmarks.security import open_as, sim_car
from benchmarks.steering import _wait_ready
from viena.common.signals import stop_on_signals
from viena.services.steering.model.signing import signed_setpoint

CAR = "viena/elettra"
#: the key that shows each program of the sim profile is back
OWN_KEY = {"router": "sim/truth", "sim": "sim/truth", "gnss0": "gnss/gnss0/fix",
           "gnss1": "gnss/gnss1/fix", "razor0": "imu/razor0/sample", "steering": "steering/state",
           "estimator": "estimator/state"}
PI_PROGRAMS = ["router", "gnss0", "gnss1", "razor0", "steering", "estimator"]
#: a setpoint signed with a lease that is not the owner's (what a flooder or a forger sends)
FOREIGN = json.dumps(signed_setpoint("not-the-lease", 5.0, seq=1)).encode()


def supervisor(env: dict):
    """supervisord's XML-RPC interface of the profile `env` runs."""
    from supervisor.xmlrpc import SupervisorTransport

    transport = SupervisorTransport(None, None, f"unix://{env['VIENA_RUN']}/supervisor.sock")
    return xmlrpc.client.ServerProxy("http://127.0.0.1", transport=transport).supervisor


def pids(env: dict) -> dict[str, int]:
    return {info["name"]: info["pid"] for info in supervisor(env).getAllProcessInfo()}


class Heard:
    """When each key of the car was heard, every time (arrival, monotonic s), with its
    `seq`, and the last value of each."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.times: dict[str, list[float]] = {}
        self.seqs: dict[str, list[tuple[float, int]]] = {}
        self.last: dict[str, dict] = {}
        self._sub = session.declare_subscriber(f"{CAR}/**", self._on)

    def _on(self, sample) -> None:
        key = str(sample.key_expr)[len(CAR) + 1:]
        try:
            value = msgpack.unpackb(sample.payload.to_bytes())
        except Exception:
            value = None
        with self.lock:
            now = time.monotonic()
            self.times.setdefault(key, []).append(now)
            if isinstance(value, dict):
                self.last[key] = value
                if isinstance(value.get("seq"), int):
                    self.seqs.setdefault(key, []).append((now, value["seq"]))

    def first_new(self, key: str, t: float) -> float | None:
        """When the first sample after `t` came that does not follow the one before it:
        a restarted publisher's (its seq starts again) or the first after an outage (its
        seq jumps). Arrival times lag when this process is busy; seqs do not."""
        with self.lock:
            heard = self.seqs.get(key, [])
            for (_, before), (arrival, seq) in zip(heard, heard[1:]):
                if arrival > t and seq != before + 1:
                    return arrival
        return None

    def rate(self, key: str, t0: float, t1: float) -> float:
        with self.lock:
            n = sum(1 for x in self.times.get(key, []) if t0 <= x <= t1)
        return n / (t1 - t0)

    def close(self) -> None:
        self._sub.undeclare()


def _wait(predicate, timeout: float, period: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


# -- 1. restart to flowing -----------------------------------------------------------------
def restarts(env: dict, heard: Heard) -> list[tuple[str, float | None, float | None]]:
    """(program, kill -> new pid RUNNING, kill -> first sample on its key from the new
    process) for each."""
    sup = supervisor(env)
    out = []
    for name in OWN_KEY:
        pid = sup.getProcessInfo(name)["pid"]
        os.kill(pid, signal.SIGKILL)
        t_kill = time.monotonic()

        def back(name=name, pid=pid) -> bool:
            info = sup.getProcessInfo(name)
            return info["statename"] == "RUNNING" and info["pid"] not in (0, pid)
        running = time.monotonic() - t_kill if _wait(back, 20) else None
        # supervisord says RUNNING only `startsecs` (1 s) after the spawn, often after the
        # program's first sample: the first sample of the new process tells
        _wait(lambda key=OWN_KEY[name], t=t_kill: heard.first_new(key, t) is not None, 20)
        first = heard.first_new(OWN_KEY[name], t_kill)
        out.append((name, running, None if first is None else first - t_kill))
        time.sleep(2.0)                                   # let the car settle before the next
    return out


# -- 2. the owner under a flood --------------------------------------------------------------
def flood(router: str, rate_hz: float, seconds: float) -> int:
    """Put setpoints with a foreign lease at `rate_hz` (a process of its own) until SIGTERM
    or `seconds`; says "flooding" on stderr once it puts, and at the end prints how many it
    put, and at what rate. The steering tests start it too."""
    import zenoh

    from viena.common.config import load_zenoh_config

    stop = stop_on_signals((signal.SIGTERM,))
    sent = 0
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
        pub = session.declare_publisher(f"{CAR}/steering/setpoint")
        print(f"flooding {CAR}/steering/setpoint at {rate_hz:.0f} puts/s", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        end = t0 + seconds
        while not stop.is_set() and (now := time.monotonic()) < end:
            due = int((now - t0) * rate_hz) - sent
            for _ in range(min(due, 1000)):
                pub.put(FOREIGN)
            sent += max(due, 0)
            time.sleep(0.005)
        elapsed = time.monotonic() - t0
    print(json.dumps({"sent": sent, "rate_hz": sent / elapsed}), flush=True)
    return 0


def owner_under_flood(samples: int, flood_rate: float) -> dict:
    from viena.services.steering.client import SteeringClient

    with processes() as start:
        router = start_router(start)
        service = start_steering(start, router, start_drive_twin(start))
        with open_as({}, router, "pilot") as session:
            _wait_ready(session)
            trips = Trips()
            state_sub = session.declare_subscriber(f"{CAR}/steering/state", trips.on_state)
            owner = SteeringClient(session)
            if owner.arm()["status"] != "accepted":
                raise RuntimeError("the owner could not arm")
            alone, rejected_alone = _stream(owner, samples)
            floods = [start("-m", "benchmarks.faults", "--flood", router, "--flood-rate", flood_rate,
                            stdout=subprocess.PIPE) for _ in range(2)]
            _stream(owner, 40)                              # 2 s: the floods reach full rate
            cpu0, t0 = {p.pid: cpu_seconds(p.pid) for p in (service, *floods)}, time.monotonic()
            loaded, rejected_loaded = _stream(owner, samples)
            cpu = {pid: (cpu_seconds(pid) - c) / (time.monotonic() - t0) for pid, c in cpu0.items()}
            for f in floods:
                f.terminate()
            rates = [json.loads(f.communicate(timeout=60)[0])["rate_hz"] for f in floods]
            owner.disarm()
            state_sub.undeclare()
    return {"alone": alone, "loaded": loaded, "rejected": rejected_alone + rejected_loaded,
            "trips": trips.watchdog, "flood_rates": rates,
            "service_cpu": cpu[service.pid], "flooders_cpu": sum(cpu.values()) - cpu[service.pid]}


class Trips:
    """From the published steering states: how often the watchdog went from ok to tripped,
    and the drive's heartbeat from ok to lost."""

    def __init__(self):
        self.watchdog = self.heartbeat = 0
        self._was = {"watchdog": "ok", "drive_heartbeat": "ok"}

    def on_state(self, sample) -> None:
        state = msgpack.unpackb(sample.payload.to_bytes())
        self.watchdog += state.get("watchdog") == "tripped" and self._was["watchdog"] == "ok"
        self.heartbeat += state.get("drive_heartbeat") == "lost" and self._was["drive_heartbeat"] == "ok"
        self._was = {name: state.get(name) for name in self._was}


def _stream(owner, samples: int) -> tuple[list[float], int]:
    """The owner's round trips at 20 Hz, small steps, arming again after a rejection (as
    a pilot would); (round trips, rejected)."""
    times, rejected = [], 0
    for k in range(samples):
        t0 = time.perf_counter()
        if owner.lease is None:                    # the arm after a rejection failed too: again
            rejected += 1
            owner.arm()
            time.sleep(0.05)
            continue
        reply = owner.setpoint(0.2 * (k % 2))
        times.append(time.perf_counter() - t0)
        if reply.get("status") == "rejected":
            rejected += 1
            owner.arm()
        time.sleep(max(0.0, 0.05 - (time.perf_counter() - t0)))
    return times, rejected


# -- 3. bad input ------------------------------------------------------------------------------
def bad_inputs(imu_sample: dict) -> list[tuple[str, str, str, bytes, int]]:
    """(what, key under viena/elettra/, put or get, payload, times): the abuse of issue 15."""
    absurd_imu = dict(imu_sample, accel_mps2=[150.0, 150.0, 150.0], gyro_radps=[30.0, -30.0, 30.0])
    future_imu = dict(imu_sample, t=imu_sample["t"] + 1_900_000_000)
    return [
        ("100 kB JSON arm", "steering/arm", "get", b'{"arm": "' + b"x" * 100_000 + b'"}', 50),
        ("900 kB JSON setpoint", "steering/setpoint", "put", b'{"a": "' + b"x" * 900_000 + b'"}', 20),
        ("2000-deep JSON", "steering/setpoint", "get", b"[" * 2000 + b"]" * 2000, 50),
        ("deep msgpack", "steering/calibration", "get", msgpack.packb({"a": [[[[[[[[[[1]]]]]]]]]]}), 50),
        ("absurd setpoint", "steering/setpoint", "get",
         json.dumps(signed_setpoint("x", 1e308, seq=1)).encode(), 100),
        ("invalid UTF-8", "steering/arm", "get", b"{\"arm\": \"\xff\xfe\"}", 100),
        ("discovery query", "**", "get", b"", 20),
        ("900 kB route", "pilot/route", "put", b'{"type": "LineString", "coordinates": "' + b"9" * 900_000 + b'"}', 20),
        ("garbage IMU sample", "imu/razor0/sample", "put", b"\xc1" * 64, 200),
        ("absurd IMU sample", "imu/razor0/sample", "put", msgpack.packb(absurd_imu), 200),
        ("future IMU sample", "imu/razor0/sample", "put", msgpack.packb(future_imu), 5),
        ("garbage GNSS fix", "gnss/gnss0/fix", "put", msgpack.packb({"t": "soon"}), 200),
    ]


def rss_around_bad_input(env: dict, session, heard: Heard) -> tuple[dict, dict, int, list]:
    """RSS of every program before the table and 3 s after it, inputs sent, and which rows
    grew which program by more than 1 MB (RSS 0.5 s after each row)."""
    _wait(lambda: "imu/razor0/sample" in heard.last, 20)
    table = bad_inputs(heard.last["imu/razor0/sample"])
    programs = pids(env)
    before = {name: rss_mb(pid) for name, pid in programs.items()}
    sent, growth, last = 0, [], dict(before)
    for what, key, how, payload, times in table:
        for _ in range(times):
            if how == "put":
                session.put(f"{CAR}/{key}", payload)
            else:
                list(session.get(f"{CAR}/{key}", payload=payload or None, timeout=1.0))
            sent += 1
            if how == "put" and sent % 20 == 0:
                time.sleep(0.01)                           # a sensor's pace, not a burst
        time.sleep(0.5)
        now = {name: rss_mb(pid) for name, pid in programs.items()}
        grew = {name: now[name] - last[name] for name in now if now[name] - last[name] > 1.0}
        if grew:
            growth.append((what, grew))
        last = now
    time.sleep(3.0)
    after = {name: rss_mb(pid) for name, pid in programs.items()}
    return before, after, sent, growth


# -- 4. a Pi-sized budget ----------------------------------------------------------------------
def pi_budget(env: dict, endpoint: str, heard: Heard, seconds: float) -> dict:
    from viena.services.steering.client import SteeringClient

    programs = pids(env)
    for name in PI_PROGRAMS:
        subprocess.run(["taskset", "-a", "-p", "-c", "0", str(programs[name])], check=True,
                       capture_output=True)
    for pid in (programs["sim"], os.getpid()):                  # the hardware, and the owner
        subprocess.run(["taskset", "-a", "-p", "-c", "1", str(pid)], check=True, capture_output=True)
    busy = subprocess.Popen(["taskset", "-c", "0", sys.executable, "-c", "while True: pass"])
    try:
        with open_as(env, endpoint, "pilot") as session:
            owner = SteeringClient(session)
            end = time.monotonic() + 90
            while owner.arm()["status"] != "accepted":           # past a sweep, if one is due
                if time.monotonic() > end:
                    raise RuntimeError("the owner could not arm")
                time.sleep(1.0)
            stop = threading.Event()
            statuses: Counter = Counter()

            def steer() -> None:
                t0 = time.monotonic()
                while not stop.is_set():
                    reply = owner.setpoint(3.0 * math.sin(time.monotonic() - t0))
                    statuses[reply.get("status")] += 1
                    if reply.get("status") == "rejected":
                        owner.arm()
                    stop.wait(0.05)
            pilot = threading.Thread(target=steer, daemon=True)
            pilot.start()
            time.sleep(1.0)
            cpu0 = {name: cpu_seconds(programs[name]) for name in [*PI_PROGRAMS, "sim"]}
            trips = Trips()
            state_sub = session.declare_subscriber(f"{CAR}/steering/state", trips.on_state)
            busy0, core0, t0 = cpu_seconds(busy.pid), core_busy_s(0), time.monotonic()
            time.sleep(seconds)
            t1 = time.monotonic()
            state_sub.undeclare()
            cpu = {name: (cpu_seconds(programs[name]) - c) / (t1 - t0) for name, c in cpu0.items()}
            cpu["busy loop"] = (cpu_seconds(busy.pid) - busy0) / (t1 - t0)
            cpu["core 0 in all"] = (core_busy_s(0) - core0) / (t1 - t0)
            stop.set()
            pilot.join(timeout=5)
            armed = heard.last.get("steering/state", {}).get("armed")
            owner.disarm()
    finally:
        busy.kill()
        busy.wait()
        subprocess.run(["taskset", "-a", "-p", "-c", f"0-{(os.cpu_count() or 1) - 1}", str(os.getpid())],
                       check=True, capture_output=True)
    rates = {key: heard.rate(key, t0, t1) for key in sorted(heard.times)}
    return {"cpu": cpu, "rates": rates, "statuses": dict(statuses), "watchdog_trips": trips.watchdog,
            "heartbeat_losses": trips.heartbeat, "armed_at_end": armed, "seconds": t1 - t0}


def core_busy_s(core: int) -> float:
    """Seconds a core has spent not idle since boot (every process on it, this machine's
    others included)."""
    with open("/proc/stat") as f:
        for line in f:
            if line.startswith(f"cpu{core} "):
                ticks = [int(x) for x in line.split()[1:]]
                return (sum(ticks) - ticks[3] - ticks[4]) / CLOCK_TICKS
    return float("nan")


# -- the report --------------------------------------------------------------------------------
def _ms(values) -> str:
    return f"p50 {percentile(values, 50) * 1e3:6.2f} ms  p99 {percentile(values, 99) * 1e3:6.2f} ms (n={len(values)})"


def _s(value: float | None) -> str:
    return "  never" if value is None else f"{value:5.2f} s"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench faults", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=200, help="owner setpoints per phase (20 Hz)")
    parser.add_argument("--flood-rate", type=float, default=10_000.0, help="puts/s of each flooder")
    parser.add_argument("--pi-seconds", type=float, default=20.0, help="the Pi-sized window")
    parser.add_argument("--flood", metavar="ROUTER", help=argparse.SUPPRESS)     # a flooder process
    parser.add_argument("--flood-seconds", type=float, default=600.0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.flood:
        return flood(args.flood, args.flood_rate, args.flood_seconds)

    print("faults benchmark: kills, a setpoint flood, bad input, and a Pi-sized core (issue 15)", flush=True)
    flood_result = owner_under_flood(args.samples, args.flood_rate)
    alone, loaded = flood_result["alone"], flood_result["loaded"]
    ratio = percentile(loaded, 99) / percentile(alone, 99)
    print(f"owner setpoint round trip alone        {_ms(alone)}")
    print(f"  under 2 x {args.flood_rate:,.0f}/s foreign flood  {_ms(loaded)}   p99 x{ratio:.2f} (goal <= 2)")
    print(f"  flooders reached {', '.join(f'{r:,.0f}/s' for r in flood_result['flood_rates'])}; owner "
          f"setpoints rejected {flood_result['rejected']}, watchdog trips {flood_result['trips']} (goal 0)")
    print(f"  CPU under the flood: steering service {flood_result['service_cpu'] * 100:.0f} %, the two "
          f"flooders {flood_result['flooders_cpu'] * 100:.0f} % of one core (this machine has 2)", flush=True)

    with tempfile.TemporaryDirectory(prefix="viena-bench-faults-") as tmp, sim_car("tcp", Path(tmp)) as (env, endpoint):
        with open_as(env, endpoint, "observer") as session:
            heard = Heard(session)
            try:
                _wait(lambda: all(k in heard.times for k in OWN_KEY.values()), 90, period=0.2)
                print("restart to flowing (SIGKILL; supervisord restarts):", flush=True)
                for name, running, flowing in restarts(env, heard):
                    print(f"  {name:10s} new pid RUNNING {_s(running)}   first {OWN_KEY[name]} {_s(flowing)}",
                          flush=True)
                before, after, sent, growth = rss_around_bad_input(env, session, heard)
                print(f"RSS before and after the bad-input table ({sent} inputs; goal +10 MB at most):")
                for name in before:
                    print(f"  {name:10s} {before[name]:7.1f} MB -> {after[name]:7.1f} MB   "
                          f"{after[name] - before[name]:+6.1f} MB")
                for what, grew in growth:
                    print(f"  grown by {what}: " + ", ".join(f"{n} {mb:+.1f} MB" for n, mb in grew.items()))
                pi = pi_budget(env, endpoint, heard, args.pi_seconds)
            finally:
                heard.close()
    print(f"Pi-sized budget: {', '.join(PI_PROGRAMS)} pinned to core 0 with a busy loop; sim and "
          f"owner on core 1; {pi['seconds']:.0f} s")
    for key in ("steering/state", "estimator/state", "imu/razor0/sample", "gnss/gnss0/fix", "gnss/gnss1/fix",
                "sim/truth"):
        print(f"  {key:22s} {pi['rates'].get(key, 0.0):6.1f} Hz")
    healths = {k: v for k, v in pi["rates"].items() if k.endswith("health")}
    print(f"  health rates           {', '.join(f'{k[:-7]} {v:.2f}' for k, v in healths.items())} Hz")
    print(f"  owner setpoints {pi['statuses']} (arming again after a rejection); watchdog trips "
          f"{pi['watchdog_trips']}, drive heartbeat losses {pi['heartbeat_losses']} (goal 0 and 0); "
          f"armed at the end: {pi['armed_at_end']}")
    print("  CPU share of one core: " + ", ".join(f"{k} {v * 100:.1f} %" for k, v in pi["cpu"].items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
