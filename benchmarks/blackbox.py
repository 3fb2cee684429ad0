"""The black box on the sim car: its size per hour, its CPU, and what a kill -9 loses.

    viena bench blackbox        (or: python -m benchmarks.blackbox [--seconds 60] [--split-s 10])

`viena up --record` on free ports (the whole sim car and viena-recorder, writing into a
temporary directory), then, printing each figure:

1. MCAP per hour: the drive's bytes over `--seconds` of the car, scaled (goal <= 250 MB);
2. the recorder's CPU, a share of one core over the same time (goal <= 5 %), and its RSS;
3. kill -9 at a random moment: supervisord restarts the recorder, which repairs the file
   the kill left; how much of the last second before the kill is missing (the newest log
   time in the repaired file against the kill's time; goal <= 1 s), and whether every
   closed file opens with the mcap reader;
4. the killed drive read as one (common/recording.py Drive): its files, samples, and the
   latched repeats (the route each file opens with) read once.
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import tempfile
import time
from pathlib import Path


def _last_log_time(path: Path) -> int | None:
    from viena.common.recording import Recording

    last = None
    for m in Recording(path).messages():
        last = m.log_time
    return last


def run(seconds: float = 60.0, split_s: float = 10.0) -> int:
    from benchmarks.faults import pids, supervisor
    from benchmarks.harness import cpu_seconds, rss_mb
    from benchmarks.security import sim_car
    from viena.common.drive_files import drive_files
    from viena.common.recording import Drive, file_size, find_drives

    with tempfile.TemporaryDirectory(prefix="viena-blackbox-") as tmp:
        drives = Path(tmp) / "drives"
        os.environ["VIENA_DRIVES"] = str(drives)
        os.environ["VIENA_RECORDER_SPLIT_S"] = str(split_s)
        with sim_car("tcp", Path(tmp), flags=("--record",)) as (env, _endpoint):
            pid = pids(env)["recorder"]
            time.sleep(3.0)                                     # the car's programs up and publishing
            c0, t0 = cpu_seconds(pid), time.monotonic()
            b0 = sum(map(file_size, drives.glob("viena-*")))
            time.sleep(seconds)
            c1, t1 = cpu_seconds(pid), time.monotonic()
            b1 = sum(map(file_size, drives.glob("viena-*")))
            per_hour = (b1 - b0) / (t1 - t0) * 3600 / 1e6
            print(f"blackbox: {t1 - t0:.0f} s of the sim car, files every {split_s:g} s")
            print(f"  MCAP per hour        {per_hour:7.1f} MB   (goal <= 250)")
            print(f"  recorder CPU         {100 * (c1 - c0) / (t1 - t0):7.2f} % of a core   (goal <= 5)")
            print(f"  recorder RSS         {rss_mb(pid):7.1f} MB")

            time.sleep(random.uniform(0.5, 3.0))                # a moment nobody chose
            killed_ns = time.time_ns()
            os.kill(pid, signal.SIGKILL)
            sup = supervisor(env)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and sup.getProcessInfo("recorder")["pid"] in (0, pid):
                time.sleep(0.2)
            time.sleep(3.0)                                     # the new run repaired the old file
            found = find_drives(drives)
            first_id, first = next(iter(found.items()))
            last = _last_log_time(first[-1])
            lost_s = (killed_ns - last) / 1e9 if last is not None else float("nan")
            print(f"  kill -9 then restart: the killed run's last file repaired ({first[-1].name}); "
                  f"{lost_s:.2f} s before the kill missing   (goal <= 1)")
            from mcap.reader import make_reader

            closed, unreadable = drive_files(drives), []
            for path in closed:
                with open(path, "rb") as f:
                    try:
                        sum(1 for _ in make_reader(f).iter_messages())
                    except Exception as exc:    # noqa: BLE001 - a file the mcap reader refuses is the finding
                        unreadable.append(f"{path.name}: {exc}")
            refused = f" (not: {'; '.join(unreadable)})" if unreadable else ""
            opened = len(closed) - len(unreadable)
            print(f"  closed files that the mcap reader opens: {opened} of {len(closed)}{refused}")
            drive = Drive(first_id, first)
            paths = sum(1 for m in drive.messages() if m.key.endswith("/pilot/path"))
            print(f"  the killed drive read as one: {len(drive.files)} files, {drive.count} samples, "
                  f"{drive.repeats} latched repeats read once, {paths} route samples")
    return 0


def main(argv: list[str] | None = None) -> int:
    """`viena bench blackbox [--seconds S] [--split-s S]`: see the module's docstring."""
    p = argparse.ArgumentParser(prog="viena bench blackbox", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=60.0, help="how long to measure the size and CPU")
    p.add_argument("--split-s", type=float, default=10.0, help="the recorder's files cover this long")
    return run(**vars(p.parse_args(argv)))


if __name__ == "__main__":
    raise SystemExit(main())
