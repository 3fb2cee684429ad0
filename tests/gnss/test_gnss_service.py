"""`viena-gnss` as a process: fixes and health on zenoh from a twin on socket://, and a
device that vanishes, sends garbage or never answers never kills it."""
from __future__ import annotations

import socket
import subprocess
import sys
import threading

import numpy as np
import pytest
from gnss_helpers import ORIGIN_ECEF, health_until, still
from vienatest import collect

from viena.common.samples.fix import FIX
from viena.common.twin.serial_port import SerialEndpoint, TwinWrapper
from viena.services.gnss.simulator import NmeaTwin, NovatelTwin

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]  # the service as a process



def gnss(procs, router, car, url, *extra):
    return procs.python("-m", "viena.services.gnss.service", "--connect", router, "--car", car,
                        "--unit", "gnss0", "--port", url, *extra)


def fixes(session, car, n, timeout=15.0):
    return collect(session, f"viena/{car}/gnss/gnss0/fix", n, timeout=timeout, decode=FIX.decode)



def near_origin(fix) -> bool:
    return np.linalg.norm(np.array(fix["ecef_m"]) - ORIGIN_ECEF) < 4 * np.linalg.norm(fix["ecef_sigma_m"])


class CorruptingTwin(TwinWrapper):
    """A twin whose line turns bad when armed: bits flip, bytes vanish, junk appears."""

    def __init__(self, inner):
        super().__init__(inner)
        self.armed = False
        self.clock = inner.clock
        self.rng = np.random.default_rng(7)

    def poll(self, now_s):
        out = bytearray(self.inner.poll(now_s))
        if self.armed and out:
            damage = self.rng.integers(0, 4)
            at = int(self.rng.integers(0, len(out)))
            if damage == 0:
                out[at] ^= 1 << int(self.rng.integers(0, 8))
            elif damage == 1:
                del out[at:at + int(self.rng.integers(1, 40))]
            elif damage == 2:
                out[at:at] = b"\xaa\x44\x12\x1c" + self.rng.bytes(int(self.rng.integers(0, 60)))
        return bytes(out)


@pytest.fixture
def endpoint():
    served = []

    def serve(twin, port=0):
        ep = SerialEndpoint(twin, port=port).start()
        served.append(ep)
        return ep
    yield serve
    for ep in served:
        ep.stop()


def test_fixes_and_health_on_zenoh(procs, zrouter, zsession, endpoint):
    ep = endpoint(NovatelTwin(still(), seed=3, outage_interval_s=0.0))
    gnss(procs, zrouter, "gnssfix", ep.url)
    got = fixes(zsession, "gnssfix", 20)
    assert len(got) == 20
    assert all(f["valid"] and f["unit"] == "gnss0" and near_origin(f) for f in got)
    assert all(b["seq"] == a["seq"] + 1 for a, b in zip(got, got[1:]))
    assert all(b["t"] - a["t"] == 50_000_000 for a, b in zip(got, got[1:]))
    assert all(0 < f["latency_s"] < 1.0 and f["t_host"] > f["t"] for f in got)
    h = health_until(zsession, "gnssfix", lambda h: h["counts"].get("fixes", 0) > 20)
    assert h["state"]["connected"] is True and h["state"]["pos_type"] == "WAAS"
    assert h["rates_hz"]["frames"] > 10
    assert h["errors"]["crc_errors"] == 0 and h["errors"]["command_failures"] == 0
    assert h["last_sample_age_s"] < 1.0


def test_a_vanished_receiver_is_reported_and_reconnected(procs, zrouter, zsession, endpoint):
    twin = NovatelTwin(still(), seed=4, outage_interval_s=0.0)
    ep = endpoint(twin)
    port = ep.port
    proc = gnss(procs, zrouter, "gnssgone", ep.url)
    assert fixes(zsession, "gnssgone", 5)
    ep.stop()                                       # the cable is pulled
    h = health_until(zsession, "gnssgone", lambda h: not h["state"]["connected"]
                     and h["errors"]["connect_failures"] > 0)
    assert h["errors"]["port_failures"] >= 1 and not h["state"]["connected"]
    assert proc.poll() is None
    endpoint(twin, port)                            # and plugged back in
    assert len(fixes(zsession, "gnssgone", 5)) == 5
    h = health_until(zsession, "gnssgone", lambda h: h["state"]["connected"])
    assert h["counts"]["reconnects"] >= 1


def test_garbage_on_the_line_is_counted_never_published(procs, zrouter, zsession, endpoint):
    twin = CorruptingTwin(NovatelTwin(still(), seed=6, outage_interval_s=0.0))
    ep = endpoint(twin)
    gnss(procs, zrouter, "gnssbad", ep.url)
    assert fixes(zsession, "gnssbad", 3)
    twin.armed = True
    got = fixes(zsession, "gnssbad", 20)
    assert len(got) == 20
    assert all(f["valid"] and near_origin(f) for f in got)      # nothing bad got through
    h = health_until(zsession, "gnssbad", lambda h: h["errors"]["crc_errors"] > 0
                     and h["errors"]["resyncs"] > 0)
    assert h["errors"]["crc_errors"] > 0 and h["errors"]["resyncs"] > 0


def test_a_receiver_that_never_answers_does_not_stop_the_service(procs, zrouter, zsession,
                                                                tmp_path):
    config = tmp_path / "gnss.toml"
    config.write_text("[gnss]\ncommand_timeout_s = 0.3\n")
    server = socket.create_server(("127.0.0.1", 0))
    conns = []
    stop = threading.Event()

    def accept():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conns.append(server.accept()[0])
            except OSError:
                pass
    threading.Thread(target=accept, daemon=True).start()
    try:
        proc = gnss(procs, zrouter, "gnssmute", f"socket://127.0.0.1:{server.getsockname()[1]}",
                    "--config", str(config))
        h = health_until(zsession, "gnssmute", lambda h: h["errors"]["connect_failures"] >= 2)
        assert h["errors"]["command_failures"] >= 2 and h["state"]["connected"] is False
        assert "no response" in h["state"]["last_error"]
        assert proc.poll() is None
    finally:
        stop.set()
        for c in conns:
            c.close()
        server.close()


def test_nmea_receiver(procs, zrouter, zsession, endpoint):
    ep = endpoint(NmeaTwin(still(), seed=8, outage_interval_s=0.0))
    gnss(procs, zrouter, "gnssnmea", ep.url, "--protocol", "nmea")
    got = fixes(zsession, "gnssnmea", 10)
    assert len(got) == 10
    assert all(f["protocol"] == "nmea" and f["valid"] and near_origin(f) for f in got)
    assert all(b["t"] - a["t"] == 100_000_000 for a, b in zip(got, got[1:]))


@pytest.mark.parametrize("args, message", [
    ([], "no receiver port"),
    (["--port", "socket://127.0.0.1:1", "--protocol", "nmea", "--config", "{toml}"],
     "setting 'dynamics' must be one of"),
])
def test_configuration_errors_are_one_line(tmp_path, args, message):
    toml = tmp_path / "gnss.toml"
    toml.write_text("[gnss]\ndynamics = 'CAR'\n")
    run = subprocess.run([sys.executable, "-m", "viena.services.gnss.service",
                          *[a.format(toml=toml) for a in args]],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 2
    assert len(run.stderr.strip().splitlines()) == 1 and message in run.stderr
