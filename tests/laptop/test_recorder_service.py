"""viena-recorder, the black box, as the pi profile runs it: a drive of split files from the
running car, its health, and a full disk that stops the recording but not the car."""
from __future__ import annotations

import json
import resource
import signal
import subprocess

import pytest
from laptop_helpers import TRUTH_KEY, VIENA, start_sim, wait_for_samples
from test_recording_damage import ENCODING, KEY, sample
from vienatest import collect_until, wait_for_subscriber, wait_until

from viena.common.recording import Recording
from viena.common.samples.health import HEALTH

pytestmark = pytest.mark.slow  # a router, the sim, the recorder as processes
HEALTH_KEY = "viena/elettra/recorder/health"


def recorder(procs, router, directory, *flags, **options):
    return procs.python("-m", "viena.services.recorder.service", "--connect", router, "--directory", directory,
                        "--log-level", "INFO", *flags, **options)


def closed(directory):
    return sorted(directory.glob("viena-*_*.mcap"))


def test_the_black_box_records_the_car_into_a_drive(tmp_path, procs, router, session):
    start_sim(procs, router, tmp_path)
    wait_for_samples(session, TRUTH_KEY)
    drives = tmp_path / "drives"
    rec = recorder(procs, router, drives, "--split-s", "1", "--keep-gb", "1")
    assert wait_until(lambda: len(closed(drives)) >= 2, 60)
    [health] = collect_until(session, HEALTH_KEY, lambda got: any(h["counts"].get("samples") for h in got),
                             timeout=15, decode=HEALTH.decode)[-1:]
    assert health["state"]["recording"] is True and health["state"]["drive"] in closed(drives)[0].name
    assert health["errors"] == {}
    rec.send_signal(signal.SIGTERM)
    assert rec.wait(timeout=10) == 0
    files = closed(drives)
    assert len(files) >= 3 and not list(drives.glob("*.part"))
    keys = {}
    for path in files:                                 # each file complete, each with the car in it
        recording = Recording(path)
        keys[path.name] = {m.key for m in recording.messages()}
        assert recording.complete, path.name
    assert all(TRUTH_KEY in k for k in list(keys.values())[:-1]), keys     # the last may be its last moment
    listed = subprocess.run([*VIENA, "record", "list", str(drives), "--json"], capture_output=True, text=True,
                            timeout=60)
    assert listed.returncode == 0, listed.stderr
    [row] = json.loads(listed.stdout)
    assert row["files"] == len(files) and row["distance_m"] is not None


def _small_disk():
    """The recorder's "disk" holds 300 kB: writing past it fails as a full disk does."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))


def test_a_full_disk_stops_the_recording_turns_the_health_red_and_the_recorder_lives(
        tmp_path, procs, router, session):
    drives = tmp_path / "drives"
    rec = recorder(procs, router, drives, "--keyexprs", "test/**", "--split-mb", "50", preexec_fn=_small_disk)
    assert wait_for_subscriber(session, KEY)
    import zenoh
    pub = session.declare_publisher(KEY, encoding=zenoh.Encoding(ENCODING),
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    for i in range(3000):                              # ~700 kB of incompressible samples
        pub.put(sample(i))
    pub.undeclare()
    red = collect_until(session, HEALTH_KEY, lambda got: any(h["errors"].get("write_failures") for h in got),
                        timeout=20, decode=HEALTH.decode)
    assert red[-1]["errors"] == {"write_failures": 1} and red[-1]["state"]["recording"] is False
    assert rec.poll() is None                          # still alive: its health says what happened
    rec.send_signal(signal.SIGTERM)
    _, err = rec.communicate(timeout=10)
    assert "cannot write" in err and "recording stopped" in err and "Traceback" not in err


def test_a_directory_it_cannot_write_is_one_line_and_a_red_health(tmp_path, procs, router, session):
    """Here: another recorder (of another car) writes into it; on the car, a card gone
    read-only. The recorder stays up and says why; the car goes on."""
    drives = tmp_path / "drives"
    first = recorder(procs, router, drives, "--car", "other")
    assert wait_until(lambda: list(drives.glob("*.part")), 30)
    second = recorder(procs, router, drives)
    red = collect_until(session, HEALTH_KEY, lambda got: any(h["errors"].get("write_failures") for h in got),
                        timeout=20, decode=HEALTH.decode)
    assert red[-1]["state"]["recording"] is False and "another recorder" in red[-1]["state"]["last_error"]
    assert second.poll() is None and first.poll() is None
    for proc in (second, first):
        proc.send_signal(signal.SIGTERM)
    _, err = second.communicate(timeout=10)
    assert "cannot record into" in err and "Traceback" not in err
    assert first.wait(timeout=10) == 0 and len(closed(drives)) == 1     # the first one's drive, untouched
