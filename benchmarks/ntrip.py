"""`viena bench ntrip` (python -m benchmarks.ntrip): the NTRIP client's figures.

- framing throughput: whole checked RTCM 3 frames per second and MB/s through the client's
  framer (pyrtcm's CRC-24Q), the headroom against a flood;
- one `viena-ntrip` process's CPU over `--seconds` (60) while the caster's twin serves it
  1 kB/s of RTCM 3 (its base's 1004/1005/1033, topped up with more observables), the goal
  being < 2 % of one core; with the age of the corrections from the twin's send to a zenoh
  subscriber's receipt (p50, p95, max);
- a flood: the twin sending `--flood-kbps` (200 kB/s, 17 times what a 115200 baud line to
  the receiver carries) for `--flood-seconds`: the client's CPU, and whether it keeps up
  (bytes published / bytes sent, and the age of what it publishes).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.harness import cpu_share, percentile, processes, start_router
from viena.common.config import load_zenoh_config
from viena.common.samples.corrections import CORRECTIONS
from viena.services.ntrip.driver.rtcm3 import Rtcm3Framer
from viena.services.ntrip.simulator.caster import CasterTwin, Mountpoint

ORIGIN = (38.7369, -9.1427, 100.0)
GPS_WEEK_S = 604_800
USER, PASSWORD = "bench", "bench-password"


def framing(seconds: float = 2.0) -> tuple[float, float]:
    """(frames/s, MB/s) through the framer, on the twin's own frames in 4 kB reads."""
    mount = Mountpoint.at(ORIGIN, 1000.0, station_id=1)
    t = 1_400_000_000.0
    stream = b"".join(f for k in range(40) for _, f in mount.frames.at(mount.messages, t + k, k == 0))
    reads = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
    framer, frames, nbytes = Rtcm3Framer(), 0, 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for r in reads:
            frames += len(framer.feed(r).types)
            nbytes += len(r)
    dt = time.perf_counter() - t0
    return frames / dt, nbytes / dt / 1e6


class Arrivals:
    """Corrections samples as a subscriber gets them: their bytes, and when each 1004 came
    (its epoch, DF004), for its age from the twin's send."""

    def __init__(self):
        self.lock = threading.Lock()
        self.bytes = 0
        self.samples = 0
        #: (1004's GPS time of week in ms, when the client read it, when it came here), monotonic s
        self.came: list[tuple[int, float, float]] = []
        #: wall clock - monotonic clock: the client stamps its samples (t) on the wall clock
        self.offset_s = time.time() - time.monotonic()

    def on_sample(self, sample) -> None:
        now = time.monotonic()
        c = CORRECTIONS.decode(sample.payload.to_bytes())
        data, read = c["data"], c["t"] / 1e9 - self.offset_s
        tows, i = [], 0
        while i < len(data):
            n = ((data[i + 1] & 3) << 8 | data[i + 2]) + 6
            if (data[i + 3] << 4 | data[i + 4] >> 4) == 1004:
                tows.append(int.from_bytes(data[i + 6:i + 10], "big") >> 2 & ((1 << 30) - 1))   # DF004
            i += n
        with self.lock:
            self.bytes += len(data)
            self.samples += 1
            self.came.extend((tow, read, now) for tow in tows)

    def ages_ms(self, caster: CasterTwin) -> tuple[list[float], list[float]]:
        """Each 1004's age from the twin's send: when the client read it, and at the subscriber."""
        sent = {round((s.epoch_gps_s % GPS_WEEK_S) * 1000): s.monotonic_s for s in list(caster.sent)
                if s.number == 1004}
        with self.lock:
            came = [(read - sent[tow], now - sent[tow]) for tow, read, now in self.came if tow in sent]
        return [a * 1e3 for a, _ in came], [b * 1e3 for _, b in came]

    def reset(self) -> None:
        with self.lock:
            self.bytes = self.samples = 0
            self.came.clear()


def live(seconds: float, flood_kbps: float, flood_seconds: float) -> dict:
    import zenoh

    mount = Mountpoint.at(ORIGIN, 1000.0, 45.0, station_id=2050)
    caster = CasterTwin(mountpoints={"VIENA0": mount}, users={USER: PASSWORD}).start()
    # the base sends bitrate() bits/s; the flood adds observables to 1 kB/s in all
    caster.flood_bytes_per_s = max(0.0, 1000.0 - mount.bitrate() / 8)
    arrivals = Arrivals()
    result: dict = {}
    with tempfile.TemporaryDirectory() as folder, processes() as start:
        login = Path(folder) / "ntrip.credentials"
        login.write_text(f"{USER}:{PASSWORD}\n")
        os.chmod(login, 0o600)
        try:
            router = start_router(start)
            client = start("-m", "viena.services.ntrip.service", "--connect", router, "--caster", "127.0.0.1",
                           "--port", str(caster.port), "--mountpoint", "VIENA0", "--credentials", str(login),
                           "--log-level", "WARNING")
            with zenoh.open(load_zenoh_config(mode="client", connect=[router])) as session:
                sub = session.declare_subscriber("viena/elettra/gnss/corrections", arrivals.on_sample)
                _wait(lambda: arrivals.samples > 3, 30.0)
                time.sleep(2.0)                                 # past start-up
                arrivals.reset()
                served0 = caster.clients[-1].bytes_sent
                result["cpu"] = cpu_share(client.pid, seconds)
                with arrivals.lock:
                    result["rate"] = arrivals.bytes / seconds
                    result["served_rate"] = (caster.clients[-1].bytes_sent - served0) / seconds
                result["ages"] = arrivals.ages_ms(caster)
                if flood_seconds > 0:
                    caster.flood_bytes_per_s = flood_kbps * 1000.0
                    time.sleep(1.0)
                    arrivals.reset()
                    served0 = caster.clients[-1].bytes_sent
                    result["flood_cpu"] = cpu_share(client.pid, flood_seconds)
                    with arrivals.lock:
                        result["flood_rate"] = arrivals.bytes / flood_seconds
                    result["flood_ages"] = arrivals.ages_ms(caster)
                    result["flood_served"] = (caster.clients[-1].bytes_sent - served0) / flood_seconds
                sub.undeclare()
        finally:
            caster.stop()
    return result


def _wait(predicate, timeout: float) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError("no corrections from viena-ntrip")
        time.sleep(0.05)


def _ages(values) -> str:
    if not values:
        return "no 1004 matched"
    return (f"p50 {percentile(values, 50):.1f} ms, p95 {percentile(values, 95):.1f} ms, "
            f"max {max(values):.1f} ms over {len(values)} frames")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench ntrip", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="CPU window at 1 kB/s")
    parser.add_argument("--flood-kbps", type=float, default=200.0, help="the flood, kB/s")
    parser.add_argument("--flood-seconds", type=float, default=10.0, help="its CPU window (0: no flood)")
    args = parser.parse_args(argv)
    frames_s, mb_s = framing()
    print(f"RTCM 3 framing (CRC-24Q by pyrtcm):  {frames_s:10,.0f} frames/s, {mb_s:.2f} MB/s")
    r = live(args.seconds, args.flood_kbps, args.flood_seconds)
    print(f"viena-ntrip CPU at {r['rate'] / 1000:.2f} kB/s:       {r['cpu'] * 100:6.2f} % of one core  (goal < 2; "
          f"over {args.seconds:g} s, the twin served {r['served_rate'] / 1000:.2f} kB/s with its HTTP framing)")
    print(f"age from the twin's send, at the client's read: {_ages(r['ages'][0])}")
    print(f"                       at a zenoh subscriber:   {_ages(r['ages'][1])}")
    if args.flood_seconds > 0:
        kept = r["flood_rate"] / r["flood_served"] if r["flood_served"] else float("nan")
        print(f"flood of {args.flood_kbps:g} kB/s: CPU {r['flood_cpu'] * 100:.1f} % of one core, published "
              f"{r['flood_rate'] / 1000:.1f} kB/s of {r['flood_served'] / 1000:.1f} kB/s served ({kept * 100:.0f} %); "
              f"age at the client's read {_ages(r['flood_ages'][0])}; at a subscriber {_ages(r['flood_ages'][1])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
