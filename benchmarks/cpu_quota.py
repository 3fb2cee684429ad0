"""A CPU budget for a group of processes: a cgroup with a CFS quota, so the pi profile runs
here with what a Raspberry Pi 4 would give it (`viena bench pi`).

A Pi 4 has four Cortex-A72 cores, each doing about a third of the work of one core of a
current x86 machine, so the Pi is emulated as 4 x 1/3 = 1.33 cores of quota: the group may
run 133 ms of CPU every 100 ms, spread over the cores it has. The quota bounds throughput,
not the speed of one thread: a single busy thread still runs at this machine's speed
until the group's quota for the period is spent, then waits for the next period. So a
program that needs more than a Pi core on its own is not caught by the quota; the figures
per program (a share of one core here, times 3 for a Pi core) are what catch it.

Both cgroup layouts are handled: v1 (a `cpu` hierarchy with cpu.cfs_quota_us) and v2
(cpu.max). Without the right to make a cgroup (not root, or no cpu controller) the
benchmark runs without a quota and says so.
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path

PERIOD_US = 100_000
V1_ROOT = Path("/sys/fs/cgroup/cpu")
V2_ROOT = Path("/sys/fs/cgroup")


class CpuQuota:
    """A cgroup named `name` allowed `cores` cores' worth of CPU; `join()` moves the calling
    process into it (use it as a Popen preexec_fn: the child and all it starts inherit it)."""

    def __init__(self, cores: float, name: str):
        self.cores, self.dir, self.why_not = cores, None, ""
        self._v2 = False
        try:
            self.dir, self._v2 = self._make(name)
        except OSError as exc:
            self.why_not = f"no cgroup with a CPU quota ({exc.strerror or exc}): measured without one"

    def _make(self, name: str) -> tuple[Path, bool]:
        quota_us = int(round(self.cores * PERIOD_US))
        if (V1_ROOT / "cpu.cfs_quota_us").exists():
            group, v2, settings = V1_ROOT / name, False, {"cpu.cfs_period_us": PERIOD_US, "cpu.cfs_quota_us": quota_us}
        elif "cpu" in (V2_ROOT / "cgroup.subtree_control").read_text().split():
            group, v2, settings = V2_ROOT / name, True, {"cpu.max": f"{quota_us} {PERIOD_US}"}
        else:
            raise OSError(0, "neither a cgroup v1 cpu hierarchy nor a v2 cpu controller")
        group.mkdir(exist_ok=True)
        try:
            for file, value in settings.items():
                (group / file).write_text(str(value))
        except OSError:
            group.rmdir()                              # not left half made
            raise
        return group, v2

    @property
    def active(self) -> bool:
        return self.dir is not None

    def join(self) -> None:
        if self.dir is not None:
            (self.dir / "cgroup.procs").write_text(str(os.getpid()))

    def pids(self) -> list[int]:
        if self.dir is None:
            return []
        return [int(p) for p in (self.dir / "cgroup.procs").read_text().split()]

    def throttling(self) -> dict[str, float]:
        """Periods the group ran in, in how many it was held back, and for how long (s)."""
        if self.dir is None:
            return {}
        stat = dict(line.split() for line in (self.dir / "cpu.stat").read_text().splitlines() if line.strip())
        throttled_s = (int(stat.get("throttled_usec", 0)) / 1e6 if self._v2
                       else int(stat.get("throttled_time", 0)) / 1e9)
        return {"periods": int(stat.get("nr_periods", 0)), "throttled_periods": int(stat.get("nr_throttled", 0)),
                "throttled_s": throttled_s}

    def remove(self, timeout: float = 10.0) -> None:
        """The group, after whatever is left in it is stopped: SIGTERM, then after `timeout`
        SIGKILL (the caller stops its processes first; this is for a run that failed half-way)."""
        if self.dir is None:
            return
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in self.pids():
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
            end = time.monotonic() + timeout
            while self.pids() and time.monotonic() < end:
                time.sleep(0.1)
        try:
            self.dir.rmdir()
        except OSError:
            pass
