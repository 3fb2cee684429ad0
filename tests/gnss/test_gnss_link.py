"""Driver and twin talking over socket:// (twins in their own process, or served from this
one where the test must look inside the twin): the car's start-up sequence, matched
responses, rejected and unanswered commands, NMEA at 10 Hz."""
from __future__ import annotations

import socket
import threading

import numpy as np
import pytest
from gnss_helpers import ORIGIN_ECEF, start_twin, still

from viena.common.twin.serial_port import SerialEndpoint
from viena.services.gnss.driver.nmea import NmeaReceiver
from viena.services.gnss.driver.novatel import (
    CommandError,
    CommandTimeout,
    MessageId,
    NovatelReceiver,
    ResponseId,
    StartupConfig,
    Trigger,
)
from viena.services.gnss.fixes import fix_from_bestxyz, fix_from_nmea
from viena.services.gnss.simulator import NovatelTwin

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]  # receivers and twins talk in real time


@pytest.fixture
def twin_endpoint():
    twin = NovatelTwin(still(), seed=5, outage_interval_s=0.0)
    endpoint = SerialEndpoint(twin).start()
    yield twin, endpoint
    endpoint.stop()


def test_startup_sequence_configures_the_receiver(twin_endpoint):
    twin, endpoint = twin_endpoint
    with NovatelReceiver(endpoint.url) as rx:
        rx.startup(StartupConfig())
        logs = [rx.read(timeout=2) for _ in range(10)]
    assert [name for name, _ in twin.history] == ["UNLOGALL", "COM", "DYNAMICS", "SBASCONTROL", "LOG"]
    assert all(text == "OK" for _, text in twin.history)
    assert twin.baud == 115200 and twin.dynamics == 0
    assert twin.sbas.keyword.name == "ENABLE"
    entry = twin.logs[MessageId.BESTXYZ]
    assert (entry.trigger, entry.period_ms) == (Trigger.ONTIME, 50)
    assert set(np.diff([m.gps_ms for m in logs])) == {50}
    assert {m.data.pos_type.name for m in logs} == {"WAAS"}       # SBAS really is enabled


def test_responses_match_their_commands_while_logs_stream(twin_endpoint):
    twin, endpoint = twin_endpoint
    with NovatelReceiver(endpoint.url) as rx:
        rx.startup(StartupConfig())
        with pytest.raises(CommandError) as err:
            rx.com(12345)
        assert err.value.response_id == ResponseId.INVALID_BAUD_RATE
        assert "INVALID BAUD RATE" in str(err.value) and err.value.text == "INVALID BAUD RATE"
        with pytest.raises(CommandError, match="REQUESTED LOG DOES NOT EXIST"):
            rx.log(999, Trigger.ONCE)
        assert rx.dynamics().ok                                     # the next one is its own
        assert rx.log(MessageId.BESTVEL, Trigger.ONTIME, 0.1).ok
        names = {rx.read(timeout=2).name for _ in range(20)}
        assert names == {"BESTXYZ", "BESTVEL"}
        assert rx.stats.command_failures == 2 and rx.stats.unmatched_responses == 0


def test_a_receiver_that_never_answers_times_out():
    server = socket.create_server(("127.0.0.1", 0))
    accepted = []
    thread = threading.Thread(target=lambda: accepted.append(server.accept()[0]), daemon=True)
    thread.start()
    try:
        rx = NovatelReceiver(f"socket://127.0.0.1:{server.getsockname()[1]}", command_timeout=0.2)
        with rx, pytest.raises(CommandTimeout, match="UNLOGALL"):
            rx.startup(StartupConfig())
        assert rx.stats.command_failures == 2       # at 9600, then at 115200
    finally:
        for conn in accepted:
            conn.close()
        server.close()


def test_novatel_twin_in_another_process(procs):
    url = start_twin(procs, "--kind", "novatel", "--seed", "9", "--outage-interval-s", "0")
    with NovatelReceiver(url) as rx:
        rx.startup(StartupConfig())
        fixes = [fix_from_bestxyz(rx.read(timeout=2), "gnss0", 0) for _ in range(20)]
        rx.shutdown()
    for fix in fixes:
        assert fix["valid"] and fix["protocol"] == "novatel"
        assert np.linalg.norm(np.array(fix["ecef_m"]) - ORIGIN_ECEF) < 4 * np.linalg.norm(fix["ecef_sigma_m"])
        assert 0.0 < fix["latency_s"] < 1.0


def test_nmea_twin_in_another_process(procs):
    url = start_twin(procs, "--kind", "nmea", "--seed", "4", "--outage-interval-s", "0")
    with NmeaReceiver(url) as rx:
        rx.open(115200)
        fixes = [rx.read(timeout=2) for _ in range(10)]
    assert set(np.diff([f.utc_ns for f in fixes])) == {100_000_000}
    for fix in fixes:
        sample = fix_from_nmea(fix, "gps0", 0)
        assert sample["valid"] and sample["protocol"] == "nmea"
        assert np.linalg.norm(np.array(sample["ecef_m"]) - ORIGIN_ECEF) < 4 * np.linalg.norm(sample["ecef_sigma_m"])
    assert rx.stats.checksum_errors == 0
