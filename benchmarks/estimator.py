"""`viena bench estimator`: how good and how fast the estimator is. Prints numbers; asserts nothing.

    accuracy    a simulated 5-minute drive (the campus loop at 3-5 m/s after 10 s parked):
                horizontal position RMSE next to the raw GNSS error of the same run, roll and
                pitch RMSE, yaw RMSE with the magnetometer and without it (once moving). Once
                with the device twins' error models (GNSS errors correlated over minutes, as
                real ones are) and once with white GNSS errors of the same size
    coverage    is the reported uncertainty honest? Over 10 seeds: how often the true
                horizontal error lies inside the reported 95 % ellipse, and the mean NEES
                (2 for an honest 2-D estimate), with white GNSS errors, with the twins'
                correlated ones, and with two receivers under one sky
    outages     10 s without GNSS every 30 s from 20 s after pulling away, at 5 and 14 m/s,
                with 4 Hz and 1 Hz fixes, 10 seeds each, on the flat road with the twins' IMU
                and on hills with an accelerometer bias: the drift at each outage's end (how
                far the estimate moved off the truth while GNSS was away: the receiver's own
                slowly varying error it followed before is not the filter's), its 95th
                percentile and worst, and how often the end error lay inside the 95 % ellipse
    timing      IMU stamps off the GNSS clock by -500 .. +500 ms, no magnetometer, 3 seeds:
                heading RMS after 60 s of driving (against the truth at the state's stamp and
                at the IMU's true time), resets, and the offset the state points at
    throughput  offline, IMU samples per second of CPU time (GNSS at 20 Hz included)
    live        viena-estimator as a process fed at 82.5 Hz IMU and 20 Hz GNSS: its CPU share

Goals (issues 6 and 13): position <= 0.6 x raw GNSS; roll/pitch <= 1 deg; yaw <= 2 deg with
the magnetometer, <= 3 deg without once moving; coverage >= 90 %; outage drift p95 <= 3 m,
none over 5 m; heading <= 3 deg RMS at 200 ms, <= 10 deg at 500 ms, no endless resets;
>= 20,000 IMU samples/s; live CPU < 10 % of a core.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from benchmarks.simdrive import Drive, DriveSamples, at_speed, periodic_outages
from viena.common.rotation import wrap_angle
from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.estimator import Estimator
from viena.services.sim.model.car import CarParams
from viena.services.sim.model.truth import IST_ORIGIN as ORIGIN  # where SimCar drives

#: chi-square, 2 degrees of freedom, 95 %: the 95 % ellipse is NEES <= this
CHI2_2D_95 = 5.991


def _settings(drive: Drive, origin, **extra) -> dict:
    arms = {"gnss0": list(drive.lever_arm_m)}
    if drive.second_antenna_m is not None:
        arms["gnss1"] = list(drive.second_antenna_m)
    return {"origin": list(origin), "gnss_lever_arm_m": arms, **extra}


def _without_mag(samples):
    return [(k, dict(s, mag_T=None) if k == "imu" else s, tr) for k, s, tr in samples]


def horizontal_cov(state: dict) -> np.ndarray:
    """The reported 2x2 horizontal position covariance (the full one when the state has it)."""
    cov = state.get("enu_cov_m2")
    if cov is not None:
        ee, en, _, nn, _, _ = cov
        return np.array([[ee, en], [en, nn]])
    var = state["enu_var_m2"]
    return np.diag(var[:2])


def nees_h(state: dict, err_h) -> float:
    """Normalised estimation error squared of the horizontal position."""
    e = np.asarray(err_h, float)
    return float(e @ np.linalg.solve(horizontal_cov(state), e))


def states_of(est, samples, every: int = 1, on_gnss=None):
    """Feed a drive to `est`; yield (state, truth) after every `every`-th IMU sample once
    the position is valid. `on_gnss(fix, truth)` sees each fix as it goes in."""
    n = 0
    for kind, sample, truth in samples:
        if kind == "gnss":
            est.add_gnss(sample)
            if on_gnss is not None:
                on_gnss(sample, truth)
            continue
        est.add_imu(sample)
        n += 1
        if n % every == 0 and (s := est.state())["position_valid"]:
            yield s, truth


def score(samples, settings: dict, every: int = 1) -> dict:
    """Feed a drive, compare the state after every `every`-th IMU sample with the truth."""
    est = Estimator(settings)
    pos, yaw, tilt, moving, gnss, t_s, nees = [], [], [], [], [], [], []

    def fix_error(fix, truth):
        if fix["valid"]:
            gnss.append(np.subtract(est.frame.enu_of_ecef(fix["ecef_m"]), truth))

    for s, truth in states_of(est, samples, every, fix_error):
        e = np.subtract(s["enu_m"], truth.enu_m)
        pos.append(e)
        nees.append(nees_h(s, e[:2]))
        t_s.append(truth.t_s)
        if not s["heading_valid"]:
            yaw.append(math.nan)
            tilt.append((math.nan, math.nan))
            moving.append(False)
            continue
        y, p, r = yaw_pitch_roll(truth.quat)
        yaw.append(wrap_angle(s["yaw_rad"] - y))
        tilt.append((s["roll_rad"] - r, s["pitch_rad"] - p))
        moving.append(truth.speed_mps > 1.0)
    pos, gnss, tilt, yaw, moving, nees = map(np.array, (pos, gnss, tilt, yaw, moving, nees))
    rms = lambda v: float(np.sqrt(np.nanmean(v ** 2)))           # noqa: E731
    return {
        "pos_h_m": float(np.sqrt(np.mean(np.sum(pos[:, :2] ** 2, axis=1)))),
        "gnss_h_m": float(np.sqrt(np.mean(np.sum(gnss[:, :2] ** 2, axis=1)))),
        "roll_deg": math.degrees(rms(tilt[:, 0])), "pitch_deg": math.degrees(rms(tilt[:, 1])),
        "yaw_deg": math.degrees(rms(yaw[moving])),
        "final": est.state(), "pos": pos, "t_s": np.array(t_s), "nees": nees,
    }


def bench_accuracy(duration_s: float) -> list[tuple]:
    rows = []
    drive = Drive(duration_s=duration_s, seed=1)
    samples = list(DriveSamples(drive))
    mag = score(samples, _settings(drive, ORIGIN, course_heading=False))
    course = score(_without_mag(samples), _settings(drive, ORIGIN))
    white_drive = Drive(duration_s=duration_s, seed=1, sensors="white")
    white = score(list(DriveSamples(white_drive)), _settings(white_drive, ORIGIN))
    rows.append(("horizontal position RMSE, twins (m)", mag["pos_h_m"], mag["gnss_h_m"],
                 f"<= 0.6 x raw = {0.6 * mag['gnss_h_m']:.2f}"))
    rows.append(("  same, no magnetometer (m)", course["pos_h_m"], course["gnss_h_m"], ""))
    rows.append(("horizontal position RMSE, white GNSS (m)", white["pos_h_m"], white["gnss_h_m"],
                 f"<= 0.6 x raw = {0.6 * white['gnss_h_m']:.2f}"))
    rows.append(("roll RMSE, about forward (deg)", mag["roll_deg"], None, "<= 1"))
    rows.append(("pitch RMSE, about right (deg)", mag["pitch_deg"], None, "<= 1"))
    rows.append(("  roll / pitch RMSE, no magnetometer (deg)",
                 max(course["roll_deg"], course["pitch_deg"]), None, "<= 1"))
    rows.append(("yaw RMSE with magnetometer (deg)", mag["yaw_deg"], None, "<= 2"))
    rows.append(("yaw RMSE without, moving (deg)", course["yaw_deg"], None, "<= 3"))
    return rows


#: the coverage cases: (label, Drive keyword arguments)
COVERAGE_CASES = (
    ("white GNSS errors", {"sensors": "white"}),
    ("twins' correlated GNSS errors", {}),
    ("twins, two receivers, one sky", {"lever_arm_m": (-0.5, 1.0, 1.5), "second_antenna_m": (0.5, 1.0, 1.5)}),
    ("twins, 1 Hz, sigmas as h/v", {"gnss_rate_hz": 1.0, "sigma_form": "hv"}),
)


def bench_coverage(duration_s: float = 100.0, seeds=range(1, 11)) -> list[tuple]:
    """Share of states whose true horizontal error is inside the reported 95 % ellipse."""
    rows = []
    for label, kw in COVERAGE_CASES:
        nees = []
        for seed in seeds:
            drive = Drive(duration_s=duration_s, seed=seed, **kw)
            r = score(list(DriveSamples(drive)), _settings(drive, ORIGIN), every=4)
            nees.append(r["nees"])
        nees = np.concatenate(nees)
        rows.append((label, 100.0 * float(np.mean(nees <= CHI2_2D_95)), float(np.mean(nees)),
                     float(np.median(nees))))
    return rows


#: the outage cases: 10 s outages every 30 s from 20 s after pulling away (at 10 s)
OUTAGE_SPEEDS_MPS = (5.0, 14.0)
OUTAGE_RATES_HZ = (4.0, 1.0)


def outage_errors(drive: Drive, settings: dict) -> tuple[list[tuple], int]:
    """(drift m, end error m, end NEES) at the end of each of the drive's outages, and the
    estimator's resets over the drive."""
    samples = list(DriveSamples(drive))
    r = score(_without_mag(samples), settings, every=1)
    e, t, nees = r["pos"][:, :2], r["t_s"], r["nees"]
    out = []
    for a, b in drive.outages:
        before, end = np.flatnonzero(t < a)[-1], np.flatnonzero(t < b)[-1]
        out.append((float(np.linalg.norm(e[end] - e[before])), float(np.linalg.norm(e[end])),
                    float(nees[end])))
    return out, r["final"]["counts"]["resets"]


#: the roads: the twins as they are (a flat road, an IMU calibrated perfectly), and hills
#: of +-5 % grade with a residual accelerometer bias of 0.05 m/s^2 per axis (each random seed its own)
OUTAGE_ROADS = ("flat", "hills + bias")


def _road(road: str, seed: int) -> dict:
    if road == "flat":
        return {}
    rng = np.random.default_rng(1000 + seed)
    return {"grade_pct": 5.0, "grade_period_m": 300.0,
            "accel_bias_mps2": tuple(float(b) for b in rng.normal(0.0, 0.05, 3))}


def bench_outages(seeds=range(1, 11), duration_s: float = 180.0, roads=OUTAGE_ROADS) -> list[tuple]:
    rows = []
    parked = CarParams().parked_s
    outages = periodic_outages(parked + 20.0, 30.0, 10.0, duration_s)
    for road in roads:
        for speed in OUTAGE_SPEEDS_MPS:
            for rate in OUTAGE_RATES_HZ:
                ends, resets = [], 0
                for seed in seeds:
                    drive = at_speed(speed, duration_s=duration_s, seed=seed, gnss_rate_hz=rate,
                                     outages=outages, **_road(road, seed))
                    errors, n = outage_errors(drive, _settings(drive, ORIGIN))
                    ends += errors
                    resets += n
                drift, end, nees = (np.array(v) for v in zip(*ends))
                rows.append((f"{road}, {speed:g} m/s, {rate:g} Hz", len(drift),
                             float(np.percentile(drift, 95)), float(drift.max()),
                             int(np.sum(drift > 5.0)), float(np.percentile(end, 95)),
                             100.0 * float(np.mean(nees <= CHI2_2D_95)), resets))
    return rows


#: the IMU's stamps later than the truth by these (s)
TIMING_LATE_S = (-0.5, -0.2, 0.0, 0.2, 0.5)


def timing_run(late_s: float, seed: int, duration_s: float = 130.0) -> dict:
    """Heading after 60 s of driving with the IMU's stamps `late_s` after the GNSS clock's."""
    drive = Drive(duration_s=duration_s, seed=seed, imu_stamps_late_s=late_s, with_mag=False)
    samples = list(DriveSamples(drive))
    truths = [tr for k, _, tr in samples if k == "imu"]
    t_ns = np.array([tr.t_ns for tr in truths])
    yaw_true = np.unwrap([yaw_pitch_roll(tr.quat)[0] for tr in truths])
    est = Estimator(_settings(drive, ORIGIN))
    at_stamp, at_true, valid, hints = [], [], [], []
    start_s = CarParams().parked_s + 60.0
    for kind, sample, truth in samples:
        if kind == "gnss":
            est.add_gnss(sample)
            continue
        est.add_imu(sample)
        if truth.t_s < start_s:
            continue
        s = est.state()
        valid.append(s["heading_valid"])
        if not s["heading_valid"]:
            continue
        stamp_yaw = np.interp(s["t"], t_ns, yaw_true)
        at_stamp.append(wrap_angle(s["yaw_rad"] - stamp_yaw))
        at_true.append(wrap_angle(s["yaw_rad"] - yaw_pitch_roll(truth.quat)[0]))
        hints.append(s.get("imu_time_offset_hint_s"))
    final = est.state()
    rms = lambda v: math.degrees(math.sqrt(np.mean(np.square(v)))) if v else math.nan   # noqa: E731
    hint = next((h for h in reversed(hints) if h is not None), None)
    return {"stamp_deg": rms(at_stamp), "true_deg": rms(at_true), "valid": float(np.mean(valid)),
            "resets": final["counts"]["resets"], "hint_s": hint}


def bench_timing(seeds=(1, 2, 3)) -> list[tuple]:
    rows = []
    for late in TIMING_LATE_S:
        runs = [timing_run(late, seed) for seed in seeds]
        hints = [r["hint_s"] for r in runs if r["hint_s"] is not None]
        rows.append((f"{late * 1e3:+.0f} ms", max(r["stamp_deg"] for r in runs),
                     max(r["true_deg"] for r in runs), min(r["valid"] for r in runs) * 100.0,
                     max(r["resets"] for r in runs),
                     f"{np.median(hints) * 1e3:+.0f} ms" if hints else "-"))
    return rows


def _feed_time(samples, settings: dict, repeats: int, with_state: bool = False) -> float:
    """Best CPU time of feeding the drive (and building a state per IMU sample)."""
    best = math.inf
    for _ in range(repeats):
        est = Estimator(settings)
        add_imu, add_gnss, state = est.add_imu, est.add_gnss, est.state
        t0 = time.process_time()
        for kind, sample in samples:
            if kind == "imu":
                add_imu(sample)
                if with_state:
                    state()
            else:
                add_gnss(sample)
        best = min(best, time.process_time() - t0)
    return best


def bench_throughput(duration_s: float, repeats: int = 3) -> list[tuple]:
    drive = Drive(duration_s=duration_s, seed=1)
    samples = [(k, s) for k, s, _ in DriveSamples(drive)]
    n_imu = sum(k == "imu" for k, _ in samples)
    settings = _settings(drive, ORIGIN)
    return [("offline throughput (IMU samples/s)", n_imu / _feed_time(samples, settings, repeats),
             None, ">= 20000"),
            ("  using every 20 Hz fix (samples/s)",
             n_imu / _feed_time(samples, {**settings, "gnss_max_rate_hz": 0.0}, repeats), None, ""),
            ("  and building a state per sample (samples/s)",
             n_imu / _feed_time(samples, settings, 1, with_state=True), None, "")]


def bench_live(seconds: float) -> list[tuple]:
    """The service fed at the real rates by this process; its CPU share from /proc."""
    import zenoh

    from benchmarks.harness import cpu_seconds, processes, start_router
    from viena.common.config import load_zenoh_config
    from viena.common.samples.fix import FIX
    from viena.common.samples.imu import SAMPLE

    drive = Drive(duration_s=seconds + 15.0, seed=6)
    samples = list(DriveSamples(drive))
    states = []
    with processes() as start:
        router = start_router(start)
        session = zenoh.open(load_zenoh_config(mode="client", connect=[router]))
        try:
            sub = session.declare_subscriber("viena/elettra/estimator/state", lambda s: states.append(1))
            imu_pub = session.declare_publisher("viena/elettra/imu/imu0/sample",
                                                encoding=zenoh.Encoding(SAMPLE.encoding))
            gnss_pub = session.declare_publisher("viena/elettra/gnss/gnss0/fix",
                                                 encoding=zenoh.Encoding(FIX.encoding))
            proc = start("-m", "viena.services.estimator.service", "--connect", router,
                         "--origin", *map(str, ORIGIN), "--log-level", "WARNING")
            time.sleep(3.0)                                   # start-up is not the steady state
            t_first = samples[0][1]["t"]
            wall0 = time.monotonic()
            measuring = None
            for kind, sample, _ in samples:
                due = wall0 + (sample["t"] - t_first) * 1e-9
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                (imu_pub if kind == "imu" else gnss_pub).put(
                    (SAMPLE if kind == "imu" else FIX).encode(sample))
                if measuring is None and time.monotonic() - wall0 > 12.0:   # aligned, navigating
                    measuring = (cpu_seconds(proc.pid), time.monotonic(), len(states))
            cpu1, wall1, n1 = cpu_seconds(proc.pid), time.monotonic(), len(states)
            sub.undeclare()
            imu_pub.undeclare()
            gnss_pub.undeclare()
        finally:
            session.close()
    cpu0, wall_start, n0 = measuring
    return [("live CPU at 82.5 Hz (% of a core)", 100 * (cpu1 - cpu0) / (wall1 - wall_start), None, "< 10"),
            ("  states published (Hz)", (n1 - n0) / (wall1 - wall_start), None, "82.5")]


def _print_rows(title: str, header: str, rows, fmt) -> None:
    print(f"\n{title}")
    print(header)
    for row in rows:
        print(fmt(*row))


def _value(v) -> str:
    if v is None:
        return ""
    return f"{v:10,.0f}" if abs(v) >= 1000 else f"{v:10.2f}"


def _real_drives(args) -> int:
    from benchmarks import drive_sources, real_drive
    from benchmarks.estimator_real import bench_drive

    for name in args.fetch or ():
        print(f"{name}: {drive_sources.fetch(name, args.source_dir)}")
    if args.fetch:
        return 0
    names = real_drive.available() if args.drive == ["all"] else args.drive
    if not names:
        print(f"no converted drives in {real_drive.DRIVES_DIR}; get some with --fetch "
              f"({', '.join(drive_sources.SOURCES)})")
        return 1
    for name in names:
        bench_drive(real_drive.load(name), seeds=range(1, args.seeds + 1), parts=tuple(args.real_parts))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="viena bench estimator", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=300.0, help="simulated drive, s (default 300)")
    parser.add_argument("--live-seconds", type=float, default=20.0, help="how long to watch the service")
    parser.add_argument("--no-live", action="store_true", help="skip the live measurement")
    parser.add_argument("--seeds", type=int, default=10, help="seeds per coverage and outage case "
                                                               "(real drives: per table, 5 is enough)")
    parser.add_argument("--only", nargs="+", metavar="PART",
                        choices=["accuracy", "coverage", "outages", "timing", "throughput", "live"],
                        help="run only these parts")
    real = parser.add_argument_group("real drives (benchmarks/estimator_real.py): judged on these first")
    real.add_argument("--drive", nargs="+", metavar="NAME",
                      help="bench the estimator on these converted drives ('all': every one there is) "
                           "instead of the simulated car")
    real.add_argument("--fetch", nargs="+", metavar="NAME",
                      help="get and convert these public drives (see benchmarks/drive_sources.py), then stop")
    real.add_argument("--from", dest="source_dir", type=Path, metavar="DIR",
                      help="with --fetch: read the drive's files from this clone (or git directory) of its "
                           "repository instead of downloading them")
    real.add_argument("--real-parts", nargs="+", default=["wandering", "white", "cases", "outages"],
                      choices=["wandering", "white", "cases", "outages"], help="with --drive: which tables")
    args = parser.parse_args(argv)
    if args.fetch or args.drive:
        return _real_drives(args)
    parts = set(args.only or ["accuracy", "coverage", "outages", "timing", "throughput", "live"])
    if args.no_live:
        parts.discard("live")
    seeds = range(1, args.seeds + 1)
    rows = []
    if "accuracy" in parts:
        rows += bench_accuracy(args.duration)
    if "throughput" in parts:
        rows += bench_throughput(args.duration)
    if "live" in parts:
        rows += bench_live(args.live_seconds)
    if rows:
        print(f"{'':56s} {'estimator':>10s} {'reference':>10s}   goal")
        for name, value, reference, goal in rows:
            print(f"{name:56s} {_value(value)} {_value(reference):>10s}   {goal}")
        print("reference: the raw GNSS error of the same run")
    if "coverage" in parts:
        _print_rows(f"coverage: true horizontal error inside the reported 95 % ellipse ({len(seeds)} seeds x 100 s; "
                    "goal >= 90 %, NEES 2 when honest)",
                    f"{'':34s} {'inside %':>9s} {'mean NEES':>10s} {'median':>8s}",
                    bench_coverage(seeds=seeds),
                    lambda label, inside, mean, median: f"{label:34s} {inside:9.1f} {mean:10.2f} {median:8.2f}")
    if "outages" in parts:
        _print_rows(f"outages: 10 s without GNSS every 30 s from 20 s after pulling away ({len(seeds)} seeds; "
                    "goal: drift p95 <= 3 m, none over 5 m)",
                    f"{'':30s} {'outages':>8s} {'drift p95':>10s} {'worst':>7s} {'> 5 m':>6s} "
                    f"{'end err p95':>12s} {'in 95 % ellipse':>16s} {'resets':>7s}",
                    bench_outages(seeds=seeds),
                    lambda label, n, p95, worst, over, end95, inside, resets:
                        f"{label:30s} {n:8d} {p95:9.2f}m {worst:6.2f}m {over:6d} {end95:11.2f}m "
                        f"{inside:15.0f}% {resets:7d}")
        print("drift: how far the estimate moved off the truth during the outage; end err: the error at "
              "its end, the receiver's own error before it included")
    if "timing" in parts:
        _print_rows("timing: IMU stamps late (+) or early (-) against the GNSS clock, no magnetometer, heading "
                    "after 60 s of driving (worst of 3 seeds; goal 3 deg RMS at 200 ms, 10 deg at 500 ms)",
                    f"{'stamps':>8s} {'yaw RMS at stamp':>17s} {'at true time':>13s} {'valid %':>8s} "
                    f"{'resets':>7s} {'hint':>9s}",
                    bench_timing(),
                    lambda label, stamp, true, valid, resets, hint:
                        f"{label:>8s} {stamp:16.2f}° {true:12.2f}° {valid:8.0f} {resets:7d} {hint:>9s}")
        print("at stamp: against the truth at the state's time; at true time: at the IMU samples' own "
              "moment; hint: the IMU time_offset_s the state suggests (t_true = t_stamped + offset)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
