"""The CPU priority of a parallel test worker and of every process it starts.

Linux shares the CPU between *autogroups* before nice counts: each session (setsid) is
an autogroup, and two busy autogroups get half each whatever the nice of the processes
inside. A car brought up by `viena up -d` is a session of its own (supervisord starts
one), so with plain nice it gets no more CPU than all the pytest workers together, and
two cars get a third of two cores each. So a worker starts a session of its own, sets
its autogroup's nice, and sets the same on the sessions that the processes it started
begin (they carry its PYTEST_XDIST_WORKER). Nice only goes up (lower priority): a process
may not take it back, so the lanes that need it start first. A session of its own is out
of the terminal's reach, so the controller passes Ctrl-C on to the workers.

Without autogroups (`kernel.sched_autogroup_enabled = 0`, or no /proc/PID/autogroup),
the plain nice of the worker, which its processes inherit, does the same job.
"""
from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

#: how often a worker looks for sessions its processes started
SCAN_PERIOD_S = 0.5


class WorkerPriority:
    """One per worker process: `lower_to(nice)` before each test."""

    def __init__(self, worker: str):
        self.tag = f"PYTEST_XDIST_WORKER={worker}".encode()
        self.nice = 0
        self._scanner: threading.Thread | None = None
        try:
            os.setsid()                      # an autogroup of its own, apart from the others
        except OSError:
            pass                             # already a session or group leader: plain nice only

    def lower_to(self, nice: int) -> None:
        if nice <= self.nice:
            return
        self.nice = nice
        os.nice(nice - os.nice(0))
        _set_autogroup_nice(os.getpid(), nice)
        if self._scanner is None:
            self._scanner = threading.Thread(target=self._scan, name="priority", daemon=True)
            self._scanner.start()

    def _scan(self) -> None:
        while True:
            for pid in _sessions_of(self.tag):
                _set_autogroup_nice(pid, self.nice)
            time.sleep(SCAN_PERIOD_S)


def forward_interrupts() -> None:
    """For the controller of a parallel run: the workers are sessions of their own, out of
    the terminal's reach, so Ctrl-C reaches the controller only. It passes it on to them,
    so that each stops its test and cleans up (cars included) as it did before."""
    previous = signal.getsignal(signal.SIGINT)

    def forward(signum, frame):
        for pid in _children():
            try:
                os.kill(pid, signal.SIGINT)
            except OSError:
                pass
        if callable(previous):
            previous(signum, frame)
        else:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, forward)


def _children() -> list[int]:
    return _pids_where(lambda pid, entry: int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                       == os.getpid())


def _sessions_of(tag: bytes) -> list[int]:
    """Session leaders whose environment carries `tag`."""
    return _pids_where(lambda pid, entry: os.getsid(pid) == pid
                       and tag in (entry / "environ").read_bytes().split(b"\0"))


def _pids_where(test) -> list[int]:
    """The other processes for which test(pid, /proc/pid) holds."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if test(int(entry.name), entry):
                found.append(int(entry.name))
        except (OSError, ValueError, IndexError):    # gone, or not ours to read
            continue
    return found


def _set_autogroup_nice(pid: int, nice: int) -> None:
    path = Path(f"/proc/{pid}/autogroup")
    try:
        current = int(path.read_text().split()[-1])
        if current < nice:
            path.write_text(str(nice))
    except (OSError, ValueError, IndexError):  # no autogroups here, or the process is gone
        pass
