"""The whole receiver end with real bytes: the driver configures the NovAtel twin for RTCMV3
on its one port, and a simulated base's RTCM 3 (1004/1005 and MSM the OEM4 cannot decode)
goes through the feed's rules to the twin, whose fixes turn differential with the base's
id. The twin's own progression (float, fixed, timeouts) is the twin's tests'."""
from __future__ import annotations

import time

import pytest
from gnss_helpers import still

from viena.common.twin.serial_port import SerialEndpoint
from viena.services.gnss.driver.novatel import NovatelReceiver, StartupConfig
from viena.services.gnss.driver.novatel.corrections import RTCM3_DECODED
from viena.services.gnss.driver.novatel.feed import CorrectionsFeed, line_bytes_per_s
from viena.services.gnss.driver.novatel.startup import CorrectionsSetup
from viena.services.gnss.simulator import NovatelTwin
from viena.services.sim.model.truth import IST_ORIGIN

base_mod = pytest.importorskip("viena.services.ntrip.simulator.base")
schedule = pytest.importorskip("viena.services.ntrip.simulator.schedule")

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]  # receiver and twin talk in real time


def test_a_base_s_rtcm3_through_the_driver_makes_the_twin_differential():
    twin = NovatelTwin(still(), seed=5, outage_interval_s=0.0)
    endpoint = SerialEndpoint(twin).start()
    rx = NovatelReceiver(endpoint.url)
    try:
        rx.startup(StartupConfig(read_config=True, ask_version=True, corrections=CorrectionsSetup("RTCMV3")))
        assert rx.corrections_format == "RTCMV3", rx.corrections_refused
        assert rx.ability.rtk == "RT-2" and "RTCMV3" in rx.ability.formats
        base = base_mod.BaseStation.at(IST_ORIGIN, baseline_m=800.0, station_id=2050)
        messages = {**schedule.RTK, 1074: 1}                # and MSM, which must not reach the twin
        feed = CorrectionsFeed("RTCMV3", RTCM3_DECODED, line_bytes_per_s(115200))
        frames = schedule.Frames(base)
        types_seen, station_ids = set(), set()
        last_gps_s = None
        differential = 0
        end = time.monotonic() + 20
        while time.monotonic() < end:
            gps_s = twin.clock.gps_ms(time.monotonic()) // 1000
            if last_gps_s is None or gps_s > last_gps_s:
                first = last_gps_s is None
                last_gps_s = gps_s
                data = b"".join(f for _, f in frames.at(messages, gps_s, first=first))
                taken = feed.take(data, "RTCMV3", time.monotonic())
                rx.write_corrections(taken.data)
                feed.wrote(taken)
            try:
                msg = rx.read(timeout=0.1)
            except Exception:                                # queue.Empty
                continue
            types_seen.add(msg.data.pos_type.name)
            if msg.data.pos_type.name in ("PSRDIFF", "NARROW_FLOAT", "NARROW_INT"):
                differential += 1
                station_ids.add(msg.data.station_id)
            if differential >= 10:
                break
        assert types_seen & {"PSRDIFF", "NARROW_FLOAT", "NARROW_INT"}, types_seen
        assert station_ids == {"2050"}, station_ids         # stn ID: the base's DF003
        assert 1074 in feed.counts.dropped_types and set(feed.counts.dropped_types) <= {1074, 1033}   # MSM, descriptors
        assert feed.counts.bytes_written > 0 and twin.overruns == 0
    finally:
        rx.close()
        endpoint.stop()
