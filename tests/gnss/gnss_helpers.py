"""Helpers shared by the GNSS tests: drive a twin by hand, read its frames, start one in
another process."""
from __future__ import annotations

import csv
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pymap3d

from viena.services.gnss.driver.novatel import FrameDecoder, Response, decode_log
from viena.services.gnss.simulator.serve import parked_truth
from viena.services.sim.model.truth import IST_ORIGIN

REPO = Path(__file__).resolve().parents[2]
SHARED_CSV = REPO.parent / "shared" / "data" / "gnss" / "novatel_bestxyz_drive_2016-06-01.csv"
ORIGIN_ECEF = np.array(pymap3d.geodetic2ecef(*IST_ORIGIN))


def still(origin=IST_ORIGIN):
    """A truth callable: the car parked at the origin."""
    truth = parked_truth(origin)
    return lambda: truth


#: The harness's GPS clock starts here (a whole second of 2016-01-01), so the phase of
#: every epoch is the same on every run.
HARNESS_GPS_MS = 1877 * 604_800_000 + 4 * 86_400_000 + 17_000


class TwinHarness:
    """Talks to a ByteTwin directly on a synthetic clock: no sockets, no sleeping."""

    def __init__(self, twin, t0: float = 1000.0):
        self.twin = twin
        self.now = t0
        self.decoder = FrameDecoder()
        self.responses: list[tuple] = []          # (header, Response)
        self.logs: list = []                      # LogMessage
        twin.clock.anchor(self.now, HARNESS_GPS_MS)
        twin.on_connect(self.now)

    def send(self, frame: bytes) -> None:
        self.twin.feed(frame, self.now)
        self.collect()

    def command(self, cmd) -> Response:
        before = len(self.responses)
        self.send(cmd.frame())
        assert len(self.responses) == before + 1, "exactly one response per command"
        return self.responses[-1][1]

    def run(self, seconds: float) -> None:
        """Advance the clock, polling the twin whenever it says it has something."""
        end = self.now + seconds
        while self.now < end:
            self.now = min(end, max(self.now + 1e-4, self.twin.next_due(self.now)))
            self.collect()

    def collect(self) -> None:
        for frame in self.decoder.feed(self.twin.poll(self.now)):
            if frame.header.is_response:
                self.responses.append((frame.header, Response.from_body(frame.body)))
            else:
                self.logs.append(decode_log(frame))


def read_csv(path=None) -> list[dict]:
    """The car's 2016 drive: the original recording when it is beside the repository,
    else the copy the product ships (test_the_shipped_recording_is_the_cars: the same)."""
    if path is None:
        from viena.services.gnss.simulator import DRIVE_CSV
        path = SHARED_CSV if SHARED_CSV.exists() else DRIVE_CSV
    with open(path, newline="") as f:
        return [{k: v.strip() for k, v in row.items()} for row in csv.DictReader(f)]


def start_twin(procs, *args: str) -> str:
    """Start `python -m viena.services.gnss.simulator ARGS` and return its URL."""
    proc = procs.start(sys.executable, "-m", "viena.services.gnss.simulator", *args,
                       stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    line = proc.stdout.readline().split()
    assert line and line[0] == "READY", f"twin did not start: {line}"
    return line[1]


def health_until(session, car, predicate, timeout=15.0, unit: str = "gnss0"):
    """A unit's health samples until one satisfies predicate; that one (or the last seen)."""
    from vienatest import collect

    from viena.common.samples.health import HEALTH
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        got = collect(session, f"viena/{car}/gnss/{unit}/health", 1, timeout=2.0, decode=HEALTH.decode)
        if got:
            last = got[0]
            if predicate(last):
                return last
    return last
