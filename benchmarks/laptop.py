"""`viena bench laptop`: the laptop tools' figures, each against the whole car's traffic.

- recorder throughput: the highest sample rate `viena record` keeps without losing one
  (goal >= 10x the car's total rate: truth 100 Hz, 2 GNSS x 20 Hz, IMU 82.5 Hz,
  steering 50 Hz, estimator 82.5 Hz, pilot 20 Hz, and a health per second from each service);
- replay timing error at 1x: when each replayed sample arrives at a subscriber, against
  its recorded log time (goal p99 <= 2 ms);
- monitor CPU, rendering on a terminal with the whole car live (goal < 10 % of a core).

The traffic comes from `CarLoad`: samples shaped like the agreed schemas, with the
simulated car's values, on every key the car uses, at the car's rates times a factor.
"""
from __future__ import annotations

import argparse
import fcntl
import heapq
import os
import pty
import signal
import struct
import subprocess
import tempfile
import termios
import threading
import time
from pathlib import Path

import msgpack

from benchmarks.harness import cpu_share, percentile, processes, start_router
from viena.common.config import load_zenoh_config
from viena.common.keys import Keys
from viena.common.recording import Recording, RecordingWriter

CAR = "bench"
#: (key under viena/<car>/, rate Hz, sample kind, schema) of the whole car
STREAMS = [
    ("sim/truth", 100.0, "truth", "viena.sim.truth/1"),
    ("gnss/gnss0/fix", 20.0, "fix", "viena.gnss.fix/1"),
    ("gnss/gnss1/fix", 20.0, "fix", "viena.gnss.fix/1"),
    ("imu/razor0/sample", 82.5, "imu", "viena.imu.sample/1"),
    ("steering/state", 50.0, "steering", "viena.steering.state/1"),
    ("estimator/state", 82.5, "estimator", "viena.estimator.state/2"),
    ("pilot/state", 20.0, "pilot", "viena.pilot.state/1"),
] + [(f"{service}/health", 1.0, "health", "viena.health/1")
     for service in ("sim", "gnss/gnss0", "gnss/gnss1", "imu/razor0", "steering", "estimator", "pilot")]
CAR_RATE_HZ = sum(rate for _, rate, _, _ in STREAMS)


def _samples(kind: str) -> dict:
    """One sample of each kind, with the fields (and so the size) of the real thing."""
    from viena.services.sim.model.car import SimCar
    from viena.services.sim.model.truth import truth_sample

    truth = truth_sample(SimCar().step(0.01))
    v3 = [0.1, -0.2, 9.81]
    return {
        "truth": truth,
        "fix": {"unit": "gnss0", "protocol": "novatel", "valid": True, "pos_status": "SOL_COMPUTED",
                "pos_type": "SINGLE", "vel_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY",
                "ecef_m": truth["ecef_m"], "ecef_sigma_m": [1.2, 0.9, 1.6], "vel_ecef_mps": v3,
                "vel_sigma_mps": [0.05] * 3, "lat_deg": truth["lat_deg"], "lon_deg": truth["lon_deg"],
                "height_m": truth["height_m"], "sats_tracked": 9, "sats_used": 8, "gps_week": 2317,
                "gps_ms": 123456, "t_host": 0, "latency_s": 0.05, "vel_latency_s": 0.025,
                "diff_age_s": None, "sol_age_s": 0.0, "time_status": "FINESTEERING"},
        "imu": {"unit": "razor0", "firmware": "viena", "accel_mps2": v3, "gyro_radps": v3,
                "mag_T": [2.6e-5, 1e-6, -3.4e-5],
                "raw": {"accel_g": v3, "gyro_dps": v3, "mag_counts": v3, "euler_deg": None},
                "board_id": 7},
        "steering": {"armed": True, "owner": "laptop", "target_rad": 0.1, "measured_rad": 0.099,
                     "watchdog_s": 0.2, "fault": None, "current_a": 1.5},
        "estimator": {"mode": "navigating", "aligned": True, "heading_valid": True,
                      "heading_source": "mag+course", "position_valid": True, "imu_live": True,
                      "gnss_live": ["gnss0", "gnss1"], "origin": truth["origin"],
                      "origin_source": "config", "enu_m": truth["enu_m"], "enu_var_m2": [0.1] * 3,
                      "enu_cov_m2": [0.1, 0.01, 0.0, 0.1, 0.0, 0.2], "enu_sigma_m": [0.32] * 3,
                      "sigma_h_m": 0.33, "sigma_v_m": 0.45, "standstill": False,
                      "imu_time_offset_hint_s": None,
                      "lat_deg": truth["lat_deg"], "lon_deg": truth["lon_deg"],
                      "height_m": truth["height_m"], "vel_enu_mps": v3, "vel_var_m2ps2": [0.01] * 3,
                      "speed_mps": 4.0, "quat": truth["quat"], "yaw_rad": 0.5, "pitch_rad": 0.0,
                      "roll_rad": 0.0, "att_var_rad2": [1e-4] * 3, "rate_body_radps": v3,
                      "accel_bias_mps2": v3, "gyro_bias_radps": v3, "gnss_used": 100,
                      "gnss_rejected": {}, "input_rejected": {}, "counts": {"imu": 1000},
                      "last_reset": None},
        "pilot": {"mode": "following", "reason": None, "controller": "pure_pursuit", "armed": True,
                  "route_points": 41, "route_length_m": 155.2, "checkpoint": 12,
                  "checkpoint_distance_m": 2.7, "checkpoint_bearing_deg": 88.1,
                  "checkpoint_heading_error_deg": -1.9, "progress_m": 43.5, "progress": 0.28,
                  "cross_track_m": 0.04, "heading_error_deg": -0.8, "wheel_cmd_deg": 6.2,
                  "lookahead_m": 5.4, "target_enu_m": [12.9, 20.3], "route_speed_mps": None,
                  "estimate_age_s": 0.012, "setpoints": 2150},
        "health": {"service": "x", "unit": None, "uptime_s": 10.0, "rates_hz": {"sample": 82.5},
                   "counts": {"sample": 825}, "errors": {}, "last_sample_age_s": 0.01, "state": {}},
    }[kind]


class CarLoad:
    """The whole car's traffic, `factor` times its rates: `schedule(seconds)` lists what to
    send when; `publish(session, seconds)` sends it on time."""

    def __init__(self, factor: float = 1.0, car: str = CAR):
        self.factor = factor
        self.keys = Keys(car)
        self.streams = [(self.keys.key(*suffix.split("/")), rate * factor, f"application/msgpack;{schema}",
                         _samples(kind)) for suffix, rate, kind, schema in STREAMS]

    @property
    def rate_hz(self) -> float:
        return sum(rate for _, rate, _, _ in self.streams)

    def schedule(self, seconds: float):
        """(offset s, stream index, seq) in time order; streams start out of phase."""
        heap = [(i / len(self.streams) / rate, i, 1) for i, (_, rate, _, _) in enumerate(self.streams)]
        heapq.heapify(heap)
        while heap and heap[0][0] < seconds:
            t, i, seq = heapq.heappop(heap)
            yield t, i, seq
            heapq.heappush(heap, (t + 1.0 / self.streams[i][1], i, seq + 1))

    def payload(self, i: int, seq: int, t_ns: int) -> bytes:
        sample = self.streams[i][3]
        sample["t"], sample["seq"] = t_ns, seq
        return msgpack.packb(sample)

    def publish(self, session, seconds: float, tokens: bool = False,
                stop: threading.Event | None = None) -> int:
        """Publish on time (catching up in bursts when late) for `seconds` or until `stop`;
        returns samples sent. `tokens`: declare each service's liveliness token too."""
        import zenoh

        pubs = [session.declare_publisher(key, encoding=zenoh.Encoding(enc))
                for key, _, enc, _ in self.streams]
        alive = [session.liveliness().declare_token(self.keys.key("alive", *key.split("/")[2:-1]))
                 for key, _, _, _ in self.streams if tokens and key.endswith("/health")]
        sent, t0 = 0, time.monotonic()
        for offset, i, seq in self.schedule(seconds):
            wait = t0 + offset - time.monotonic()
            if wait > 0.0005:
                if stop is not None and stop.wait(wait):
                    break
                time.sleep(0 if stop is not None else wait)
            pubs[i].put(self.payload(i, seq, time.time_ns()))
            sent += 1
        for entity in [*pubs, *alive]:
            entity.undeclare()
        return sent


def _session(router: str):
    import zenoh
    return zenoh.open(load_zenoh_config(mode="client", connect=[router]))


def _wait_for_line(stream, text: str, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = stream.readline()
        if text in line:
            return
        if not line:
            time.sleep(0.05)
    raise TimeoutError(f"no {text!r} from the process")


# -- recorder throughput ---------------------------------------------------------------------
def recorder_step(start, router: str, factor: float, seconds: float, tmp: Path) -> tuple[int, int, float]:
    """Record the car's traffic at `factor` x; (published, recorded, achieved rate)."""
    out = tmp / f"x{factor:g}.mcap"
    rec = start("-m", "viena.cli", "record", f"viena/{CAR}/**", "--connect", router, "-o", out,
                "-q", "--log-level", "WARNING", stderr=subprocess.PIPE, text=True)
    _wait_for_line(rec.stderr, "recording")
    time.sleep(0.5)                                   # its subscription reaches the router
    load = CarLoad(factor)
    with _session(router) as session:
        t0 = time.monotonic()
        sent = load.publish(session, seconds)
        achieved = sent / (time.monotonic() - t0)
        time.sleep(1.0)
    rec.send_signal(signal.SIGINT)
    rec.communicate(timeout=60)
    recorded = sum(1 for _ in Recording(out).messages())
    out.unlink()
    return sent, recorded, achieved


def recorder_throughput(seconds: float, factors=(10, 20, 40, 80)) -> float:
    best = 0.0
    with processes() as start, tempfile.TemporaryDirectory() as tmp:
        router = start_router(start)
        for factor in factors:
            sent, recorded, achieved = recorder_step(start, router, factor, seconds, Path(tmp))
            lost = sent - recorded
            print(f"  x{factor:<3g} asked {CAR_RATE_HZ * factor:7.0f}/s, published {achieved:7.0f}/s: "
                  f"{recorded}/{sent} recorded, {lost} lost", flush=True)
            if lost:
                break
            best = achieved
            if achieved < 0.9 * CAR_RATE_HZ * factor:
                break                                 # the publisher is the limit now
    return best


# -- replay timing -----------------------------------------------------------------------------
def replay_timing(seconds: float) -> tuple[list[float], int, int]:
    """Replay a recording of the car at 1x; errors of arrival times against log times (s)."""
    load = CarLoad(1.0)
    t0 = time.time_ns()
    with processes() as start, tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "car.mcap"
        writer = RecordingWriter(path)
        expected = {}
        for offset, i, seq in load.schedule(seconds):
            key, _, enc, _ = load.streams[i]
            log_time = t0 + int(offset * 1e9)
            writer.write(key, enc, log_time, load.payload(i, seq, log_time))
            expected[(key, seq)] = log_time / 1e9
        writer.close()
        router = start_router(start)
        arrivals = {}

        def on_sample(s) -> None:
            now = time.monotonic()
            arrivals[(str(s.key_expr), msgpack.unpackb(s.payload.to_bytes())["seq"])] = now
        with _session(router) as session:
            sub = session.declare_subscriber(f"viena/{CAR}/**", on_sample)
            time.sleep(0.5)
            player = start("-m", "viena.cli", "replay", path, "--connect", router,
                           "--log-level", "WARNING", stderr=subprocess.PIPE, text=True)
            _, said = player.communicate(timeout=seconds + 60)
            print(f"  replay: {said.strip()}", flush=True)
            time.sleep(0.5)
            sub.undeclare()
    offsets = [arrivals[k] - expected[k] for k in arrivals if k in expected]
    middle = percentile(offsets, 50)
    return [abs(o - middle) for o in offsets], len(arrivals), len(expected)


# -- monitor CPU -------------------------------------------------------------------------------
def monitor_cpu(seconds: float) -> float:
    """The monitor on a 160x60 pseudo-terminal, with the whole car live at 1x."""
    with processes() as start:
        router = start_router(start)
        with _session(router) as session:
            stop_load = threading.Event()
            feeder = threading.Thread(target=CarLoad(1.0).publish, daemon=True,
                                      args=(session, 3600.0, True, stop_load))
            feeder.start()
            master, slave = pty.openpty()
            fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 60, 160, 0, 0))
            env = {**os.environ, "TERM": "xterm-256color"}
            mon = start("-m", "viena.cli", "monitor", "--connect", router, "--car", CAR,
                        stdin=slave, stdout=slave, stderr=slave, env=env)
            os.close(slave)
            drain = threading.Thread(target=_drain, args=(master,), daemon=True)
            drain.start()
            time.sleep(3.0)                                   # start-up and first frames
            share = cpu_share(mon.pid, seconds)
            mon.send_signal(signal.SIGTERM)
            mon.wait(timeout=10)
            stop_load.set()
            feeder.join(timeout=5)
            os.close(master)
    return share


def _drain(fd: int) -> None:
    try:
        while os.read(fd, 65536):
            pass
    except OSError:
        pass


def sleep_overshoot(n: int = 1000, period: float = 0.0027) -> list[float]:
    """How late a bare time.sleep wakes up on this machine now: the floor of any timing."""
    late = []
    for _ in range(n):
        due = time.monotonic() + period
        time.sleep(period)
        late.append(time.monotonic() - due)
    return late


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench laptop", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each measurement")
    args = parser.parse_args(argv)
    print(f"the car's total rate: {CAR_RATE_HZ:.1f} samples/s", flush=True)
    print("recorder throughput (viena record, whole car's keys, factor x the car's rates):", flush=True)
    best = recorder_throughput(args.seconds)
    print(f"recorder sustains without loss:      {best:.0f} samples/s = {best / CAR_RATE_HZ:.0f}x "
          f"the car  (goal >= 10x)", flush=True)
    floor = sleep_overshoot()
    print(f"this machine's time.sleep overshoot:  p50 {percentile(floor, 50) * 1e3:.2f} ms, "
          f"p99 {percentile(floor, 99) * 1e3:.2f} ms  (the floor of the replay's timing)", flush=True)
    errors, got, sent = replay_timing(2 * args.seconds)
    print(f"replay timing error at 1x:           p50 {percentile(errors, 50) * 1e3:.2f} ms, "
          f"p99 {percentile(errors, 99) * 1e3:.2f} ms, max {max(errors) * 1e3:.2f} ms over "
          f"{got}/{sent} samples  (goal p99 <= 2)", flush=True)
    share = monitor_cpu(2 * args.seconds)
    print(f"monitor CPU, whole car live:         {share * 100:.1f} % of one core  (goal < 10)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
