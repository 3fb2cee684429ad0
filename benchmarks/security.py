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

3. An outsider without a certificate (issue 24): a secured `viena router` while something
   holds its TLS port: 150 or 60 silent TCP connections (re-opened as the router drops
   them), 150 that each sent one byte, or connections opened, sent a few bytes and closed
   20 times a second; a certificate holder opens a zenoh session, --choke-tries times:
   how long it took, or that it failed (zenoh gives up after 10 s). With --choke-compare
   also on a router with zenoh's own defaults (10 s handshake timeout, nothing deferred);
   with --choke-nftables also behind the limits per source address that
   docs/placement.md describes for the Pi (the outsider on 127.0.0.2).
   Goal: a certificate holder connects within 5 s, 10 of 10, with 150 silent connections.
4. Query floods (issue 24): router, EPOS twin and `viena-steering` as processes (as `viena
   bench faults`); the owner's setpoint round trip at 20 Hz alone, then while two
   processes ask arm and setpoint queries (alternately, arbitrary payloads) at
   --flood-rate each without waiting for answers; watchdog trips and drive faults (the
   steering state's `fault`, e.g. an EMCY), --runs times.
   Goal: p99 at most 2 x alone, 0 watchdog trips, 0 drive faults.

    python -m benchmarks.security --parts choke,queries --choke-compare
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import selectors
import socket
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, cast

from benchmarks.harness import cpu_seconds, free_port, percentile, processes, wait_for_port
from viena.common.config import load_zenoh_config
from viena.common.secure import secure_client
from viena.keys_cli import main as keys_main

VIENA = [sys.executable, "-m", "viena.cli"]
CAR = "viena/elettra"


@contextmanager
def sim_car(link: str, work: Path, flags: tuple[str, ...] = ()):
    """The sim profile on free ports, on `link` (tcp or tls), `viena up` given `flags`
    besides (--rtk); yields (env, router endpoint)."""
    env = dict(os.environ, VIENA_RUN=str(work / f"run-{link}"), VIENA_KEYS=str(work / "keys"))
    for name in ("VIENA_ROUTER_PORT", "VIENA_LINK", "VIENA_IDENTITY"):
        env.pop(name, None)
    if link == "tls" and not (work / "keys").exists():
        keys_main(["--keys", env["VIENA_KEYS"], "init"])
    flags = (*flags, "--secure") if link == "tls" else flags
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


# -- 3. an outsider holding the TLS port ---------------------------------------------------
class Outsider(threading.Thread):
    """Holds `n` TCP connections to the router's port (`say` bytes sent on each, none by
    default), opening a new one for each the router drops; or, with `churn`, opens one,
    sends a few bytes and closes it, `n` times a second."""

    def __init__(self, port: int, n: int, say: bytes = b"", churn: bool = False, source: str = "127.0.0.1"):
        super().__init__(daemon=True)
        self.port, self.n, self.say, self.churn, self.source = port, n, say, churn, source
        self.stop = threading.Event()
        self.opened = 0

    def run(self) -> None:
        if self.churn:
            while not self.stop.wait(1.0 / self.n):
                with contextlib.suppress(OSError), \
                        socket.create_connection(("127.0.0.1", self.port), 1.0, (self.source, 0)) as s:
                    s.sendall(b"\x16\x03\x01 not a hello")
                self.opened += 1
            return
        with selectors.DefaultSelector() as held:
            for _ in range(self.n):
                self._open(held)
            while not self.stop.is_set():
                for key, _ in held.select(0.05):
                    sock = cast(socket.socket, key.fileobj)
                    try:
                        dropped = not sock.recv(4096)
                    except OSError:
                        dropped = True
                    if dropped:
                        held.unregister(sock)
                        sock.close()
                        self._open(held)
            for key in list(held.get_map().values()):
                cast(socket.socket, key.fileobj).close()

    def _open(self, held) -> None:
        s = socket.socket()
        s.bind((self.source, 0))
        s.setblocking(False)
        s.connect_ex(("127.0.0.1", self.port))
        select.select([], [s], [], 1.0)               # connected (the router's kernel answers)
        if self.say:
            with contextlib.suppress(OSError):
                s.send(self.say)
        held.register(s, selectors.EVENT_READ)
        self.opened += 1


#: (what the outsider does, Outsider's arguments)
OUTSIDERS: list[tuple[str, dict[str, Any]]] = [
    ("nobody", {"n": 0}), ("150 silent", {"n": 150}), ("60 silent", {"n": 60}),
    ("150 that sent one byte", {"n": 150, "say": b"\x16"}),
    ("20/s connect, send, close", {"n": 20, "churn": True})]


def connect_times(config: str, tries: int) -> list[float | None]:
    """Seconds each zenoh session took to open, one try a second (None: it failed)."""
    import zenoh

    times: list[float | None] = []
    for _ in range(tries):
        t0 = time.monotonic()
        try:
            zenoh.open(zenoh.Config.from_json5(config)).close()
            times.append(time.monotonic() - t0)
        except zenoh.ZError:
            times.append(None)
        time.sleep(1.0)
    return times


#: the limits per source address of docs/placement.md, on one port, for --choke-nftables
NFTABLES = """
table inet viena_probe {{
  set sessions {{ type ipv4_addr; size 65535; flags dynamic; }}
  set attempts {{ type ipv4_addr; size 65535; flags dynamic,timeout; timeout 60s; }}
  chain input {{
    type filter hook input priority filter; policy accept;
    tcp dport {port} ct state new add @attempts {{ ip saddr limit rate over 4/second burst 16 packets }} drop
    tcp dport {port} ct state new add @sessions {{ ip saddr ct count over 16 }} reject with tcp reset
  }}
}}
"""


@contextmanager
def nftables(port: int | None):
    """NFTABLES on `port` while in the block (None: nothing)."""
    if port is None:
        yield
        return
    subprocess.run(["nft", "-f", "-"], input=NFTABLES.format(port=port), text=True, check=True)
    try:
        yield
    finally:
        subprocess.run(["nft", "delete", "table", "inet", "viena_probe"], check=True)


def choke(work: Path, tries: int, guarded: bool, firewall: bool = False) -> dict[str, list[float | None]]:
    """Per outsider of OUTSIDERS: the certificate holder's connect times, on a router as
    `viena router` makes it (guarded) or with zenoh's defaults; with `firewall`, NFTABLES
    on its port and the outsider on another address (127.0.0.2) than the holder."""
    keys = work / "keys"
    if not keys.exists():
        keys_main(["--keys", str(keys), "init"])
    flags = [] if guarded else ["--tls-handshake-timeout-ms", "0", "--defer-accept-s", "0"]
    out = {}
    with processes() as start:
        for name, how in OUTSIDERS:
            port = free_port()
            router = start("-m", "viena.router", "--listen", f"tls/127.0.0.1:{port}", "--keys", keys,
                           *flags, stderr=subprocess.PIPE, text=True)
            # it says so once its listeners defer silent connections (a connection made
            # before that, while zenoh starts, is not deferred)
            while "listening on" not in (said := router.stderr.readline()):
                if not said:
                    raise RuntimeError("the router did not start")
            config = subprocess.run([*VIENA, "keys", "--keys", str(keys), "zenoh-config", "pilot", "--connect",
                                     f"tls/localhost:{port}"], capture_output=True, text=True, check=True).stdout
            with nftables(port if firewall else None):
                outsider = Outsider(port, **how, source="127.0.0.2" if firewall else "127.0.0.1")
                if how["n"]:
                    outsider.start()
                    time.sleep(12.0)                # past zenoh's 10 s handshake timeout
                out[name] = connect_times(config, tries)
                outsider.stop.set()
            router.terminate()
            router.wait(timeout=10)
    return out


def report_choke(results: dict[str, dict[str, list[float | None]]]) -> None:
    print("a certificate holder opening a zenoh session while an outsider holds the TLS port "
          "(seconds, or FAIL: zenoh gave up after 10 s):")
    for router, by_outsider in results.items():
        print(f"  {router}:")
        for name, times in by_outsider.items():
            ok = [t for t in times if t is not None]
            within = sum(1 for t in ok if t <= 5.0)
            shown = " ".join("FAIL" if t is None else f"{t:.2f}" for t in times)
            print(f"    {name:28s} within 5 s {within:2d}/{len(times)}, max {max(ok, default=float('nan')):5.2f} s   "
                  f"[{shown}]", flush=True)


# -- 4. query floods --------------------------------------------------------------------------
def query_flood(router: str, rate_hz: float, seconds: float) -> int:
    """Ask arm and setpoint queries, alternately, at `rate_hz` without waiting for answers
    (a process of its own) until SIGTERM or `seconds`; says "flooding" on stderr once it
    asks, and at the end prints how many it asked, and at what rate."""
    import signal

    import zenoh

    from benchmarks.faults import FOREIGN
    from viena.common.signals import stop_on_signals

    stop = stop_on_signals((signal.SIGTERM,))
    asks = [(f"{CAR}/steering/arm", b'{"arm": "flood"}'), (f"{CAR}/steering/setpoint", FOREIGN)]
    sent = 0
    with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
        print(f"flooding arm and setpoint queries at {rate_hz:.0f}/s", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        end = t0 + seconds
        while not stop.is_set() and (now := time.monotonic()) < end:
            due = int((now - t0) * rate_hz) - sent
            for k in range(min(due, 1000)):
                key, payload = asks[(sent + k) % 2]
                session.get(key, payload=payload, handler=lambda reply: None, timeout=1.0)
            sent += max(due, 0)
            time.sleep(0.005)
        elapsed = time.monotonic() - t0
    print(json.dumps({"sent": sent, "rate_hz": sent / elapsed}), flush=True)
    return 0


class CpuShares:
    """Each process's share of one core from now to `since()`."""

    def __init__(self, pids: dict[str, int]):
        self.pids, self.t0 = pids, time.monotonic()
        self.c0 = {name: cpu_seconds(pid) for name, pid in pids.items()}

    def since(self) -> dict[str, float]:
        elapsed = time.monotonic() - self.t0
        return {name: (cpu_seconds(pid) - self.c0[name]) / elapsed for name, pid in self.pids.items()}


def owner_under_query_flood(samples: int, flood_rate: float, router_config: Path | None) -> dict:
    """The owner's round trips alone and under two query flooders; trips and faults."""
    from benchmarks.faults import Trips, _stream
    from benchmarks.harness import start_drive_twin, start_steering
    from benchmarks.steering import _wait_ready
    from viena.services.steering.client import SteeringClient

    class TripsAndFaults(Trips):
        def __init__(self):
            super().__init__()
            self.faults: list[str] = []

        def on_state(self, sample) -> None:
            import msgpack

            super().on_state(sample)
            fault = msgpack.unpackb(sample.payload.to_bytes()).get("fault") or ""
            if fault and (not self.faults or self.faults[-1] != fault):
                self.faults.append(fault)

    with processes() as start:
        port = free_port()
        router_proc = start("-m", "viena.router", "--listen", f"tcp/127.0.0.1:{port}", "--log-level", "WARNING",
                            *(["--zenoh-config", router_config] if router_config else []))
        wait_for_port(port)
        router = f"tcp/127.0.0.1:{port}"
        service = start_steering(start, router, start_drive_twin(start))
        with open_as({}, router, "pilot") as session:
            _wait_ready(session)
            trips = TripsAndFaults()
            state_sub = session.declare_subscriber(f"{CAR}/steering/state", trips.on_state)
            owner = SteeringClient(session)
            if owner.arm()["status"] != "accepted":
                raise RuntimeError("the owner could not arm")
            shares = CpuShares({"steering": service.pid, "router": router_proc.pid})
            alone, rejected_alone = _stream(owner, samples)
            cpu_alone = shares.since()
            floods = [start("-m", "benchmarks.security", "--query-flood", router, "--flood-rate", flood_rate,
                            stdout=subprocess.PIPE) for _ in range(2)]
            _stream(owner, 40)                              # 2 s: the floods reach full rate
            shares = CpuShares({"steering": service.pid, "router": router_proc.pid,
                                **{f"flooder {k + 1}": f.pid for k, f in enumerate(floods)}})
            loaded, rejected_loaded = _stream(owner, samples)
            cpu_loaded = shares.since()
            for f in floods:
                f.terminate()
            rates = [json.loads(f.communicate(timeout=60)[0])["rate_hz"] for f in floods]
            owner.disarm()
            state_sub.undeclare()
    return {"alone": alone, "loaded": loaded, "rejected": rejected_alone + rejected_loaded,
            "trips": trips.watchdog, "heartbeats": trips.heartbeat, "faults": trips.faults,
            "flood_rates": rates, "cpu_alone": cpu_alone, "cpu_loaded": cpu_loaded}


def report_queries(runs: list[dict], flood_rate: float) -> None:
    print(f"the owner's setpoint round trip at 20 Hz, alone and under 2 x {flood_rate:,.0f}/s arm and "
          f"setpoint queries (goal: p99 <= 2 x alone, 0 trips, 0 faults):")
    for k, r in enumerate(runs):
        a50, a99, l50, l99 = (_ms(r[w], q) for w in ("alone", "loaded") for q in (50, 99))
        print(f"  run {k + 1}: alone p50 {a50:6.2f} p99 {a99:6.2f} ms; flooded p50 {l50:6.2f} p99 {l99:6.2f} ms "
              f"(x{l99 / a99:.2f}); watchdog trips {r['trips']}, heartbeat losses {r['heartbeats']}, "
              f"faults {r['faults'] or 0}, owner rejected {r['rejected']}; flooders "
              f"{', '.join(f'{x:,.0f}/s' for x in r['flood_rates'])}", flush=True)
        for phase in ("alone", "loaded"):
            print(f"         CPU {phase:6s} " + ", ".join(f"{name} {share * 100:.0f} %"
                                                       for name, share in r[f"cpu_{phase}"].items()), flush=True)


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
    parser.add_argument("--parts", default="cost,choke,queries",
                        help="which parts, comma-separated: cost (1 and 2), choke (3), queries (4)")
    parser.add_argument("--seconds", type=float, default=20.0, help="hop and CPU window per run")
    parser.add_argument("--setpoints", type=int, default=300, help="setpoint queries per run")
    parser.add_argument("--rounds", type=int, default=3, help="alternating one-hop rounds (1000 samples each)")
    parser.add_argument("--choke-tries", type=int, default=10, help="sessions the certificate holder opens")
    parser.add_argument("--choke-compare", action="store_true", help="also on a router with zenoh's defaults")
    parser.add_argument("--choke-nftables", action="store_true",
                        help="also with docs/placement.md's nftables limits per source address on the "
                             "router's port (needs root and nft; adds, then deletes, table inet viena_probe)")
    parser.add_argument("--flood-rate", type=float, default=1500.0, help="queries/s of each query flooder")
    parser.add_argument("--samples", type=int, default=200, help="owner setpoints per phase (20 Hz)")
    parser.add_argument("--runs", type=int, default=1, help="query-flood runs")
    parser.add_argument("--router-config", type=Path, default=None,
                        help="the router's JSON5 for the query floods (default router.json5)")
    parser.add_argument("--query-flood", metavar="ROUTER", help=argparse.SUPPRESS)     # a flooder process
    parser.add_argument("--flood-seconds", type=float, default=600.0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.query_flood:
        return query_flood(args.query_flood, args.flood_rate, args.flood_seconds)
    parts = set(args.parts.split(","))
    with tempfile.TemporaryDirectory(prefix="viena-bench-security-") as tmp:
        if "cost" in parts:
            print("security benchmark: one router hop, then the sim profile, on plain TCP and with TLS + "
                  "access control", flush=True)
            with _quiet():
                hops = one_hop(Path(tmp), args.rounds, 1000)
                results = {link: measure(link, Path(tmp), args.seconds, args.setpoints) for link in ("tcp", "tls")}
            report(hops, results)
        if "choke" in parts:
            with _quiet():
                chokes = {"viena router": choke(Path(tmp), args.choke_tries, guarded=True)}
                if args.choke_compare:
                    chokes["zenoh's defaults"] = choke(Path(tmp), args.choke_tries, guarded=False)
                if args.choke_nftables:
                    chokes["viena router + nftables"] = choke(Path(tmp), args.choke_tries, True, firewall=True)
                    if args.choke_compare:
                        chokes["zenoh's defaults + nftables"] = choke(Path(tmp), args.choke_tries, False, True)
            report_choke(chokes)
        if "queries" in parts:
            runs = [owner_under_query_flood(args.samples, args.flood_rate, args.router_config)
                    for _ in range(args.runs)]
            report_queries(runs, args.flood_rate)
    return 0


if __name__ == "__main__":
    sys.exit(main())
