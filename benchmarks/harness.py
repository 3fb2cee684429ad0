"""Small measuring tools the benchmarks share: CPU share of a process, percentiles,
and a router + process harness on free ports."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def cpu_share(pid: int, seconds: float) -> float:
    """Fraction of one core a process used over the next `seconds`."""
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    return (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def memory_mb(pid: int) -> tuple[float, float] | None:
    """(resident now, its peak) of a process in MB; None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
    except (FileNotFoundError, ProcessLookupError):
        return None
    return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024


def pss_mb(pid: int) -> float | None:
    """Proportional memory of a process in MB: its own pages, and each page it shares (the
    Python interpreter, zenoh's library, numpy's) divided among the processes mapping it.
    What it adds to a machine's memory, where RSS counts a shared page in every process;
    None once it is gone."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
    except (FileNotFoundError, ProcessLookupError):
        return None
    return int(fields["Pss"].split()[0]) / 1024


def rss_mb(pid: int) -> float:
    """Resident memory of a (running) process now, MB."""
    found = memory_mb(pid)
    if found is None:
        raise ProcessLookupError(pid)
    return found[0]


def percentile(values, q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = min(len(ordered) - 1, max(0, int(round(q / 100 * (len(ordered) - 1)))))
    return ordered[k]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_port(port: int, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port}")


@contextmanager
def processes():
    """Start python modules as subprocesses; all are stopped (SIGTERM, then kill) at exit."""
    started: list[subprocess.Popen] = []

    def start(*args: str, **kw) -> subprocess.Popen:
        kw.setdefault("stdout", subprocess.DEVNULL)
        kw.setdefault("stderr", subprocess.DEVNULL)
        proc = subprocess.Popen([sys.executable, *map(str, args)], **kw)
        started.append(proc)
        return proc
    try:
        yield start
    finally:
        for proc in started:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in started:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def start_drive_twin(start) -> str:
    """The EPOS twin on a free port (a fast sweep, so calibration takes no time); its
    slcan URL for the steering service or a bus watcher."""
    port = free_port()
    start("-m", "viena.services.steering.simulator", "--port", port, "--sweep-speed-qc-s", 200_000,
          "--log-level", "ERROR")
    wait_for_port(port)
    return f"socket://127.0.0.1:{port}"


def start_steering(start, router: str, url: str):
    """`viena-steering` on the drive at `url`, connected to `router`; its process."""
    return start("-m", "viena.services.steering.service", "--connect", router, "--interface", "slcan",
                 "--channel", url, "--log-level", "ERROR")


def start_router(start) -> str:
    """A `viena router` on a free loopback port, via a `processes()` starter."""
    port = free_port()
    start("-m", "viena.router", "--listen", f"tcp/127.0.0.1:{port}", "--log-level", "WARNING")
    wait_for_port(port)
    return f"tcp/127.0.0.1:{port}"
