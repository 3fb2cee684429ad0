"""Serial twins in memory (``mem://NAME``): the unchanged drivers open them through
`open_link` and decode the real twins' bytes, on the wall clock here as on the lockstep
runner's virtual clock; one host at a time, as on a serial port."""
from __future__ import annotations

import numpy as np
import pytest
import serial

from viena.common import clock
from viena.common.link import SerialLink, open_link
from viena.common.lockstep.links import MemoryEndpoint, MemoryLink, MemoryPorts, ports_of
from viena.common.lockstep.scheduler import VirtualClock
from viena.services.gnss.driver.nmea import NmeaReceiver
from viena.services.gnss.driver.novatel import MessageId, NovatelReceiver, StartupConfig, Trigger
from viena.services.gnss.simulator import NmeaTwin, NovatelTwin
from viena.services.gnss.simulator.serve import parked_truth
from viena.services.imu.driver import Razor
from viena.services.imu.simulator import BANNER, RazorTwin
from viena.services.imu.simulator.scenarios import fixed_truth
from viena.services.sim.model.truth import IST_ORIGIN

pytestmark = pytest.mark.timeout(60)


def parked():
    truth = parked_truth(IST_ORIGIN)
    return lambda: truth


@pytest.fixture
def serve():
    """Serve twins on this thread's clock (the wall clock's ports); stopped after the test."""
    served: list[MemoryEndpoint] = []

    def serve(twin, name: str) -> MemoryEndpoint:
        served.append(ports_of().serve(twin, name).start())
        return served[-1]

    yield serve
    for endpoint in served:
        endpoint.stop()


def razor_twin(**kw) -> RazorTwin:
    return RazorTwin(lambda: fixed_truth(yaw=0.3, gyro=(0, 0, 0.1)), boot_s=0.1, **kw)


def test_open_link_picks_the_transport_by_url():
    assert type(open_link("mem://gnss0")) is MemoryLink
    assert type(open_link("loop://", 115200)) is SerialLink
    link = open_link("socket://127.0.0.1:1")
    assert type(link) is SerialLink and link.baudrate == 9600 and link.carries_break is False
    mem = open_link("mem://razor0", 500_000)
    assert (mem.name, mem.baudrate, mem.carries_break) == ("razor0", 500_000, False)


def test_the_novatel_driver_configures_its_twin_and_decodes_its_logs(serve):
    twin = NovatelTwin(parked(), seed=5, outage_interval_s=0.0)
    endpoint = serve(twin, "gnss0")
    with NovatelReceiver(endpoint.url) as rx:
        rx.startup(StartupConfig())                         # no break: the link carries none
        assert rx.log(MessageId.BESTVEL, Trigger.ONTIME, 0.1).ok
        logs = [rx.read(timeout=2) for _ in range(12)]
    assert [name for name, _ in twin.history] == ["UNLOGALL", "COM", "DYNAMICS", "SBASCONTROL", "LOG", "LOG"]
    assert all(text == "OK" for _, text in twin.history)
    assert {m.name for m in logs} == {"BESTXYZ", "BESTVEL"}
    xyz = [m.gps_ms for m in logs if m.name == "BESTXYZ"]
    assert set(np.diff(xyz)) == {50}
    assert rx.stats.crc_errors == rx.stats.unmatched_responses == rx.stats.command_failures == 0
    assert endpoint.host is None and endpoint.connects == 1


def test_the_nmea_driver_decodes_its_twins_epochs(serve):
    endpoint = serve(NmeaTwin(parked(), seed=3, outage_interval_s=0.0), "gnss1")
    with NmeaReceiver(endpoint.url) as rx:
        rx.open()
        fixes = [rx.read(timeout=2) for _ in range(5)]
    assert set(np.diff([f.utc_ns for f in fixes])) == {100_000_000}
    assert all(f.quality == 1 and f.lat_deg is not None for f in fixes)
    assert rx.stats.checksum_errors == rx.stats.parse_errors == 0


def test_the_imu_driver_reads_the_boot_text_then_frames(serve):
    twin = razor_twin(rate_hz=300.0)
    endpoint = serve(twin, "razor0")
    with Razor(endpoint.url) as imu:
        readings = [imu.read(timeout=2) for _ in range(30)]
        assert list(imu.board_text) == list(BANNER)
        assert imu.stats.crc_errors == imu.stats.resyncs == 0
    assert [r.seq for r in readings] == list(range(30))
    assert all(b.t_ns > a.t_ns for a, b in zip(readings, readings[1:]))
    assert twin.connects == 1 and endpoint.bytes_sent > 30 * 52


def test_one_host_at_a_time_and_a_closed_link_makes_room(serve):
    twin = razor_twin()
    endpoint = serve(twin, "razor0")
    first = Razor("mem://razor0").open()
    with pytest.raises(serial.SerialException) as refused:
        Razor("mem://razor0").open()
    assert str(refused.value) == "mem://razor0: another host holds the line (one at a time, as on a serial port)"
    assert endpoint.refused == 1 and endpoint.host is first.link
    assert first.read(timeout=2) is not None                # the holder was not disturbed
    first.close()
    with Razor("mem://razor0") as second:                   # a fresh cable: the board boots again
        assert second.read(timeout=2).seq == 0
        assert list(second.board_text) == list(BANNER)
    assert twin.connects == 2


def test_an_unknown_name_is_one_line_naming_what_is_served(serve):
    serve(razor_twin(), "razor0")
    serve(NmeaTwin(parked()), "gnss1")
    with pytest.raises(serial.SerialException) as err:
        Razor("mem://razor9").open()
    assert str(err.value) == ("mem://razor9: no twin is served under that name "
                              "(served here: mem://gnss1, mem://razor0)")
    with pytest.raises(OSError, match=r"^mem://x: no twin is served under that name \(served here: none\)$"):
        MemoryLink("mem://x", ports=MemoryPorts()).open()


def test_a_hung_up_line_fails_the_hosts_reads_and_a_stopped_name_is_free(serve):
    endpoint = serve(razor_twin(), "razor0")
    imu = Razor("mem://razor0").open()
    endpoint.hang_up()                                     # what a killed program's socket does
    with pytest.raises(serial.SerialException, match="mem://razor0: the line was hung up"):
        imu.link.read(0.01)
    imu.close()
    with Razor("mem://razor0") as again:
        assert again.read(timeout=2) is not None
    with pytest.raises(ValueError, match="mem://razor0 is served already"):
        serve(razor_twin(), "razor0")
    endpoint.stop()
    serve(razor_twin(), "razor0")                          # the stopped endpoint's name is free


def test_on_a_virtual_clock_the_reader_drives_the_twin_in_virtual_time():
    with VirtualClock(watchdog_s=10.0) as vc:
        ports = ports_of()
        assert ports is ports_of(vc) and ports is not ports_of(clock.REAL)   # each clock has its own
        ports.serve(NovatelTwin(parked(), seed=5, outage_interval_s=0.0), "gnss0")
        t0 = clock.monotonic()
        with NovatelReceiver("mem://gnss0") as rx:
            rx.startup(StartupConfig())
            logs = [rx.read(timeout=2) for _ in range(200)]
        assert set(np.diff([m.gps_ms for m in logs])) == {50}
        assert 9.9 < clock.monotonic() - t0 < 10.2                           # 200 logs at 20 Hz
        assert vc.errors == []
    assert "gnss0" not in ports_of().names()
