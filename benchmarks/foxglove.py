"""`viena bench foxglove`: the Foxglove bridge and export, against the simulated car.

- bridge CPU with the whole car's keys and one client subscribed to every channel
  (goal < 10 % of a core), and with no client;
- latency from a zenoh put to the WebSocket frame a client reads, p50/p99: a probe
  publishes health samples stamped with the wall clock at 50 Hz beside the car;
- what a client that stops reading for 10 s costs: the bridge's memory, and how many of
  the messages of those 10 s it still gets (the SDK keeps `--backlog` per client and
  drops the oldest; the kernel's socket buffers hold some more);
- export speed, samples/s, of a recording of the same car.

The car: the sim with two GNSS twins and an IMU twin, both GNSS services, the IMU service
and the estimator (no steering drive: it needs the slcan hub), on a router of its own.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import socket
import struct
import subprocess
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

import msgpack

from benchmarks.harness import cpu_share, free_port, percentile, processes, rss_mb, start_router
from viena.common.config import load_zenoh_config
from viena.common.paths import compose_dir
from viena.common.recording import ReceiveClock, Recording, RecordingWriter
from viena.common.samples.health import HEALTH

CAR = "benchfox"
PROBE_KEY = f"viena/{CAR}/bench/health"
PROBE_HZ = 50.0
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


class Reader:
    """A WebSocket client subscribed to every channel, reading in a thread: counts frames
    and, for the probe's channel, the delay from the probe's stamp to the frame."""

    def __init__(self, port: int, receive_buffer: int | None = None):
        from websockets.sync.client import connect

        sock = socket.socket()
        if receive_buffer:                               # a small one: the client looks slow sooner
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        sock.connect(("127.0.0.1", port))
        self._stack = ExitStack()
        self.ws = self._stack.enter_context(connect(
            f"ws://127.0.0.1:{port}", sock=sock, subprotocols=SUBPROTOCOLS, max_size=None, max_queue=1,
            compression=None, ping_interval=None))
        self.channels: dict[int, dict] = {}
        self.frames: list[tuple[int, int]] = []          # (log time of the message, channel id)
        self.delays_s: list[float] = []
        self.reading = threading.Event()
        self.reading.set()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def subscribe_when(self, topics: set[str], timeout: float = 90.0) -> None:
        end = time.monotonic() + timeout
        while not topics <= {c["topic"] for c in self.channels.values()}:
            if time.monotonic() > end:
                raise TimeoutError(f"the bridge did not advertise {sorted(topics)}")
            try:
                frame = self.ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                self.channels.update({c["id"]: c for c in json.loads(frame)["channels"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": cid, "channelId": cid} for cid in self.channels]}))
        self._thread.start()

    def _loop(self) -> None:
        probe = next((cid for cid, c in self.channels.items() if c["topic"] == PROBE_KEY), None)
        while True:
            self.reading.wait()
            try:
                frame = self.ws.recv()
            except Exception:
                return
            if isinstance(frame, bytes) and frame[0] == 1:
                now = time.time_ns()
                sub, log_time = struct.unpack_from("<IQ", frame, 1)
                self.frames.append((log_time, sub))
                if sub == probe:
                    self.delays_s.append((now - json.loads(frame[13:])["t"]) / 1e9)

    def close(self) -> None:
        self.reading.set()
        self._stack.close()


#: a process that subscribes to the whole car and does nothing with it: the floor of any
#: Python subscriber's CPU (zenoh's threads, one Python call per sample)
BARE_SUBSCRIBER = """
import sys, threading, zenoh
from viena.common.config import load_zenoh_config
session = zenoh.open(load_zenoh_config(mode="client", connect=[sys.argv[1]]))
subscriber = session.declare_subscriber(sys.argv[2], lambda sample: None)
threading.Event().wait()
"""


def start_car(start, router: str) -> None:
    for name in ("GNSS0", "GNSS1", "RAZOR0"):
        os.environ[f"VIENA_{name}_PORT"] = str(free_port())
    common = ("--connect", router, "--car", CAR, "--config", str(compose_dir() / "sim.toml"),
              "--log-level", "WARNING")
    start("-m", "viena.services.sim.service", *common, "--device", "gnss0", "--device", "gnss1", "--device", "razor0")
    for unit in ("gnss0", "gnss1"):
        start("-m", "viena.services.gnss.service", *common, "--unit", unit)
    start("-m", "viena.services.imu.service", *common, "--unit", "razor0")
    start("-m", "viena.services.estimator.service", *common)


def probe(session, stop: threading.Event) -> None:
    """Health samples stamped with the wall clock when put, at PROBE_HZ."""
    seq, period = 0, 1.0 / PROBE_HZ
    next_at = time.monotonic()
    while not stop.is_set():
        seq += 1
        sample = {"t": time.time_ns(), "seq": seq, "service": "bench", "uptime_s": 1.0, "rates_hz": {},
                  "counts": {}, "errors": {}}
        session.put(PROBE_KEY, msgpack.packb(sample), encoding=HEALTH.encoding)
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))


def record(session, path: Path):
    """Records every sample of the car while the benchmark runs (for the export figure)."""
    writer, clock, lock = RecordingWriter(path), ReceiveClock(), threading.Lock()

    def on_sample(s) -> None:
        with lock:
            writer.write(str(s.key_expr), str(s.encoding), clock(), s.payload.to_bytes())
    return writer, session.declare_subscriber(f"viena/{CAR}/**", on_sample), lock


def main(argv=None) -> int:
    import zenoh

    from viena.foxglove_export import export_foxglove

    parser = argparse.ArgumentParser(prog="viena bench foxglove", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each CPU measurement")
    parser.add_argument("--cpu-only", action="store_true",
                        help="only the bridge's CPU (with a client, then without) and latency: no slow "
                             "client, floor or export")
    args = parser.parse_args(argv)
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    with processes() as start, tempfile.TemporaryDirectory() as tmp:
        router = start_router(start)
        start_car(start, router)
        bridge = start("-m", "viena.foxglove", "--connect", router, "--car", CAR, "--port", "0",
                       "--log-level", "WARNING", stderr=subprocess.PIPE, text=True)
        port = int(re.search(r"ws://127\.0\.0\.1:(\d+)", _line_with(bridge.stderr, "serving")).group(1))
        session = zenoh.open(load_zenoh_config(mode="client", connect=[router]))
        stop = threading.Event()
        threading.Thread(target=probe, args=(session, stop), daemon=True).start()
        writer, recorder, lock = record(session, Path(tmp) / "drive.mcap")
        car_topics = {f"viena/{CAR}/{k}" for k in ("sim/truth", "gnss/gnss0/fix", "gnss/gnss1/fix",
                                                  "imu/razor0/sample", "estimator/state",
                                                  "foxglove/estimator/location")} | {PROBE_KEY}
        client = Reader(port)
        client.subscribe_when(car_topics)
        time.sleep(2.0)
        client.delays_s.clear()
        n0 = len(client.frames)
        share = cpu_share(bridge.pid, args.seconds)
        rate = (len(client.frames) - n0) / args.seconds
        delays = list(client.delays_s)
        print(f"bridge CPU, whole car, one client on every channel: {share * 100:.1f} % of one core "
              f"({rate:.0f} messages/s to it)  (goal < 10)", flush=True)
        print(f"latency zenoh put -> WebSocket frame read: p50 {percentile(delays, 50) * 1e3:.2f} ms, "
              f"p99 {percentile(delays, 99) * 1e3:.2f} ms, max {max(delays) * 1e3:.2f} ms over {len(delays)}",
              flush=True)

        if not args.cpu_only:
            slow = Reader(port, receive_buffer=4096)
            slow.subscribe_when(car_topics)
            time.sleep(1.0)
            slow.reading.clear()                             # reads nothing from here
            before_mb, t0 = rss_mb(bridge.pid), time.time_ns()
            time.sleep(10.0)
            after_mb, t1 = rss_mb(bridge.pid), time.time_ns()
            slow.reading.set()
            time.sleep(5.0)
            sent = sum(1 for t, _ in client.frames if t0 <= t < t1)
            got = sum(1 for t, _ in slow.frames if t0 <= t < t1)
            print(f"a client reading nothing for 10 s: bridge RSS {before_mb:.1f} -> {after_mb:.1f} MB; of the "
                  f"{sent} messages of those 10 s it got {got} afterwards ({sent - got} dropped); the other "
                  f"client got {sum(1 for t, _ in client.frames if t0 <= t < t1) / 10:.0f} messages/s meanwhile",
                  flush=True)
            slow.close()
        client.close()
        time.sleep(1.0)                                  # the client's unsubscribe reaches the bridge
        idle = cpu_share(bridge.pid, args.seconds)
        print(f"bridge CPU, whole car, no client:                   {idle * 100:.1f} % of one core", flush=True)
        if args.cpu_only:
            stop.set()
            session.close()
            print(f"load average after: {os.getloadavg()[0]:.1f}", flush=True)
            return 0
        bare = start("-c", BARE_SUBSCRIBER, router, f"viena/{CAR}/**")
        time.sleep(2.0)
        floor = cpu_share(bare.pid, args.seconds / 2)
        print(f"a bare Python subscriber to the whole car (floor):  {floor * 100:.1f} % of one core", flush=True)
        stop.set()
        recorder.undeclare()
        with lock:
            writer.close()
        session.close()
        recording = Recording(writer.path)
        began = time.perf_counter()
        done = export_foxglove(recording, Path(tmp) / "drive-fox.mcap")
        took = time.perf_counter() - began
        print(f"export --format foxglove: {done.samples / took:.0f} samples/s ({done.samples} samples, "
              f"{done.messages} messages, {took:.2f} s)", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}", flush=True)
    return 0


def _line_with(stream, text: str, timeout: float = 60.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = stream.readline()
        if text in line:
            return line
        if not line:
            break
    raise TimeoutError(f"the bridge never said {text!r}")


if __name__ == "__main__":
    raise SystemExit(main())
