"""`viena bench security`: what TLS and access control cost, on the whole simulated car.

1. One hop, alone: a `viena router` process and two clients (a publisher with the sim's
   identity, an observer subscribing to every key) at 100 Hz, 400-byte samples, plain TCP
   and TLS + access control in alternating rounds so both see the same machine.
2. The whole car: the sim profile runs on plain TCP and then as the car runs (`viena up
   --secure`: TLS with every program's certificate, the router's access control), each
   while a laptop-like observer subscribes to every key:
   - the simulated car's truth (100 Hz) from its `t` to the observer, through the router;
   - setpoint query round trip: a pilot arms the steering and asks for setpoints at 50 Hz;
   - router CPU at the car's full rate (every device, the estimator and the observer).
   These share two cores with every process of the car, so they vary more run to run.

Goal: TLS adds at most 30 % to the p99 figures and 2 % of a core to the router.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from benchmarks.harness import cpu_seconds, percentile
from viena.common.config import load_zenoh_config
from viena.common.secure import secure_client
from viena.keys import main as keys_main

VIENA = [sys.executable, "-m", "viena.cli"]
CAR = "viena/elettra"


@contextmanager
def sim_car(link: str, work: Path):
    """The sim profile on free ports, on `link` (tcp or tls); yields (env, router endpoint)."""
    env = dict(os.environ, VIENA_RUN=str(work / f"run-{link}"), VIENA_KEYS=str(work / "keys"))
    for name in ("VIENA_ROUTER_PORT", "VIENA_LINK", "VIENA_IDENTITY"):
        env.pop(name, None)
    if link == "tls" and not (work / "keys").exists():
        keys_main(["--keys", env["VIENA_KEYS"], "init"])
    flags = ["--secure"] if link == "tls" else []
    up = subprocess.run([*VIENA, "up", "-d", "--free-ports", *flags], env=env, capture_output=True,
                        text=True, timeout=120)
    try:
        if up.returncode != 0:
            raise RuntimeError(f"viena up failed: {up.stderr}")
        saved = json.loads((Path(env["VIENA_RUN"]) / "env.json").read_text())
        yield env, f"{link}/localhost:{saved['VIENA_ROUTER_PORT']}"
    finally:
        subprocess.run([*VIENA, "down", "--profile", "sim"], env=env, capture_output=True, timeout=60)


def open_as(env: dict, endpoint: str, identity: str):
    import zenoh

    from viena.common.keystore import KeyStore

    conf = load_zenoh_config(mode="client", connect=[endpoint])
    if endpoint.startswith("tls/"):
        secure_client(conf, KeyStore(env["VIENA_KEYS"], "elettra"), identity)
    return zenoh.open(conf)


def router_pid(env: dict) -> int:
    run = env["VIENA_RUN"]
    out = subprocess.run([sys.executable, "-m", "supervisor.supervisorctl", "-s", f"unix://{run}/supervisor.sock",
                          "pid", "router"], env=env, capture_output=True, text=True, timeout=10).stdout
    return int(out.strip())


def hop_and_cpu(env: dict, endpoint: str, seconds: float) -> tuple[list[float], float]:
    """Truth latency at an observer subscribed to every key, and the router's CPU share."""
    from viena.common.schema import unpack

    latencies: list[float] = []
    lock = threading.Lock()

    def on_sample(sample) -> None:
        now = time.time_ns()
        if str(sample.key_expr).endswith("/sim/truth"):
            t = unpack(sample.payload.to_bytes())["t"]
            with lock:
                latencies.append((now - t) / 1e9)

    with open_as(env, endpoint, "observer") as session:
        sub = session.declare_subscriber(f"{CAR}/**", on_sample)
        time.sleep(2.0)                                   # settle
        with lock:
            latencies.clear()
        pid = router_pid(env)
        c0, t0 = cpu_seconds(pid), time.monotonic()
        time.sleep(seconds)
        cpu = (cpu_seconds(pid) - c0) / (time.monotonic() - t0)
        sub.undeclare()
    with lock:
        return list(latencies), cpu


def setpoint_round_trips(env: dict, endpoint: str, count: int) -> list[float]:
    from viena.services.steering.client import SteeringClient

    with open_as(env, endpoint, "pilot") as session:
        client = SteeringClient(session)
        end = time.monotonic() + 90
        while (reply := client.arm())["status"] != "accepted":      # the twin sweeps first
            if time.monotonic() > end:
                raise RuntimeError(f"cannot arm: {reply}")
            time.sleep(1.0)
        angle, times = reply["angle_deg"], []
        try:
            for k in range(count):
                t0 = time.perf_counter()
                answer = client.setpoint(angle + 0.2 * (k % 2))
                times.append(time.perf_counter() - t0)
                if answer["status"] == "rejected":
                    raise RuntimeError(f"setpoint rejected: {answer}")
                time.sleep(0.02)
        finally:
            client.disarm()
    return times


def one_hop(work: Path, rounds: int, samples: int) -> dict[str, list[float]]:
    """Latency of one router hop at 100 Hz, per link, rounds alternating."""
    from benchmarks.harness import free_port, processes, wait_for_port

    keys = str(work / "keys")
    if not (work / "keys").exists():
        keys_main(["--keys", keys, "init"])
    env = {"VIENA_KEYS": keys}
    out: dict[str, list[float]] = {"tcp": [], "tls": []}
    with processes() as start:
        for _ in range(rounds):
            for link in ("tcp", "tls"):
                port = free_port()
                router = start("-m", "viena.router", "--listen", f"{link}/127.0.0.1:{port}",
                               "--keys", keys, "--log-level", "ERROR")
                wait_for_port(port)
                out[link] += _hop_round(env, f"{link}/localhost:{port}", samples)
                router.terminate()
                router.wait(timeout=10)
    return out


def _hop_round(env: dict, endpoint: str, samples: int) -> list[float]:
    latencies: list[float] = []
    with open_as(env, endpoint, "sim") as publisher, open_as(env, endpoint, "observer") as observer:
        sub = observer.declare_subscriber(
            f"{CAR}/**", lambda s: latencies.append(
                (time.monotonic_ns() - int.from_bytes(s.payload.to_bytes()[:8], "little")) / 1e9))
        pub = publisher.declare_publisher(f"{CAR}/sim/truth")
        time.sleep(1.0)
        latencies.clear()
        padding = b"x" * 392
        for _ in range(samples):
            pub.put(time.monotonic_ns().to_bytes(8, "little") + padding)
            time.sleep(0.01)
        time.sleep(0.2)
        pub.undeclare()
        sub.undeclare()
    return latencies


def measure(link: str, work: Path, seconds: float, setpoints: int) -> dict:
    with sim_car(link, work) as (env, endpoint):
        round_trips = setpoint_round_trips(env, endpoint, setpoints)   # also waits for the car
        hops, cpu = hop_and_cpu(env, endpoint, seconds)
    return {"hop": hops, "rtt": round_trips, "cpu": cpu}


def _ms(values, q) -> float:
    return percentile(values, q) * 1e3


def report(hops: dict, results: dict) -> None:
    plain, tls = results["tcp"], results["tls"]
    rows = [
        ("one hop alone p50 (ms)", _ms(hops["tcp"], 50), _ms(hops["tls"], 50)),
        ("one hop alone p99 (ms)", _ms(hops["tcp"], 99), _ms(hops["tls"], 99)),
        ("car: truth to observer p50 (ms)", _ms(plain["hop"], 50), _ms(tls["hop"], 50)),
        ("car: truth to observer p99 (ms)", _ms(plain["hop"], 99), _ms(tls["hop"], 99)),
        ("car: setpoint round trip p50 (ms)", _ms(plain["rtt"], 50), _ms(tls["rtt"], 50)),
        ("car: setpoint round trip p99 (ms)", _ms(plain["rtt"], 99), _ms(tls["rtt"], 99)),
        ("car: router CPU (% of a core)", plain["cpu"] * 100, tls["cpu"] * 100),
    ]
    print(f"{'':36} {'tcp':>9} {'tls+acl':>9} {'change':>9}")
    for name, a, b in rows:
        change = f"{(b - a):+.2f}" if "CPU" in name else f"{(b / a - 1) * 100:+.0f} %"
        print(f"{name:36} {a:9.2f} {b:9.2f} {change:>9}")
    print(f"(n: one hop {len(hops['tcp'])}/{len(hops['tls'])}, truth {len(plain['hop'])}/{len(tls['hop'])}, "
          f"setpoints {len(plain['rtt'])}/{len(tls['rtt'])})")


@contextmanager
def _quiet():
    """`viena keys init` prints its table; the benchmark prints only figures."""
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        yield


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench security", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="hop and CPU window per run")
    parser.add_argument("--setpoints", type=int, default=300, help="setpoint queries per run")
    parser.add_argument("--rounds", type=int, default=3, help="alternating one-hop rounds (1000 samples each)")
    args = parser.parse_args(argv)
    print("security benchmark: one router hop, then the sim profile, on plain TCP and with TLS + access control")
    with tempfile.TemporaryDirectory(prefix="viena-bench-security-") as tmp, _quiet():
        hops = one_hop(Path(tmp), args.rounds, 1000)
        results = {link: measure(link, Path(tmp), args.seconds, args.setpoints) for link in ("tcp", "tls")}
    report(hops, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
