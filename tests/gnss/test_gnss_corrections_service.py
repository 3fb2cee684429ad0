"""`viena-gnss --corrections RTCMV3` as a process: the corrections samples on zenoh reach the
receiver's port as whole frames of the types it decodes, within the line's rate; a format the
receiver cannot take is one line and a health state, and the fixes keep flowing; health says
the receiver's model, firmware and formats. The receiver is the NovAtel twin with the
corrections commands answered by corrections_helpers.CorrectionsReceiver."""
from __future__ import annotations

import time

import pytest
from corrections_helpers import CorrectionsReceiver, rtcm3
from gnss_helpers import health_until, still
from vienatest import collect

from viena.common.errors import ConfigError
from viena.common.rtcm3 import Rtcm3Framer as Rtcm3Splitter
from viena.common.samples.corrections import CORRECTIONS, corrections_sample
from viena.common.samples.fix import FIX
from viena.common.service import build_parser
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.gnss.service import GnssService, ReceiverCorrections
from viena.services.gnss.simulator import NovatelTwin

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]  # the service as a process
DIFFERENTIAL = ("PSRDIFF", "NARROW_FLOAT", "NARROW_INT")



@pytest.fixture
def receiver():
    served = []

    def serve(**kw):
        twin = CorrectionsReceiver(NovatelTwin(still(), seed=3, outage_interval_s=0.0), **kw)
        served.append(SerialEndpoint(twin).start())
        return twin, served[-1].url
    yield serve
    for ep in served:
        ep.stop()


def gnss(procs, router, car, url, log_path, *extra):
    return procs.python("-m", "viena.services.gnss.service", "--connect", router, "--car", car,
                        "--unit", "gnss0", "--port", url, *extra, stderr=open(log_path, "w"))



def publish(session, car, data: bytes, seq: int, fmt: str = "RTCMV3"):
    import zenoh
    sample = corrections_sample(time.time_ns(), seq, "127.0.0.1:2101/TEST", data, fmt,
                                Rtcm3Splitter().feed(data) and [f.type for f in Rtcm3Splitter().feed(data)])
    session.put(f"viena/{car}/gnss/corrections", CORRECTIONS.encode(sample),
                encoding=zenoh.Encoding(CORRECTIONS.encoding))


def test_corrections_reach_the_receiver_as_whole_frames_it_decodes(procs, zrouter, zsession, receiver, tmp_path):
    twin, url = receiver()
    log = tmp_path / "gnss.log"
    gnss(procs, zrouter, "rtkflow", url, log, "--corrections", "RTCMV3")
    h = health_until(zsession, "rtkflow", lambda h: h["state"].get("corrections_state") == "waiting")
    assert h["state"]["receiver_model"] == "RT2WA" and h["state"]["receiver_rtk"] == "RT-2"
    assert h["state"]["receiver_formats"] == ["RTCM", "RTCA", "CMR", "RTCMV3"]
    assert twin.names[-1] == "INTERFACEMODE"
    good = rtcm3(1005, 19) + rtcm3(1004, 180)
    for seq in range(5):
        publish(zsession, "rtkflow", good + rtcm3(1074, 150) + rtcm3(1084, 120), seq)
        time.sleep(0.2)
    h = health_until(zsession, "rtkflow", lambda h: h["counts"].get("corrections_samples", 0) >= 5)
    assert bytes(twin.corrections) == good * 5
    assert h["counts"]["corrections_bytes_written"] == 5 * len(good)
    assert h["counts"]["corrections_dropped_type"] == 5 * (156 + 126)
    assert h["state"]["corrections_dropped_types"] == {"1074": 5, "1084": 5}
    assert h["state"]["corrections_state"] in ("flowing", "waiting") and h["state"]["corrections_age_s"] >= 0
    assert h["errors"]["corrections_dropped_flood"] == 0
    assert len(collect(zsession, "viena/rtkflow/gnss/gnss0/fix", 5, decode=FIX.decode)) == 5
    procs.stop_all()
    text = log.read_text()
    assert text.count("dropping RTCM") == 1, text
    assert "reset relies on the far end treating a new connection as a break" in text      # socket://
    assert "gnss0: dropping RTCM 1074, 1084 (MSM): firmware 2.310 decodes 1001-1006" in text


def test_a_format_the_receiver_cannot_take_is_one_line_and_the_fixes_flow(procs, zrouter, zsession, receiver,
                                                                           tmp_path):
    twin, url = receiver(model="3151R", firmware="2.200")
    log = tmp_path / "gnss.log"
    gnss(procs, zrouter, "rtkrefused", url, log, "--corrections", "RTCMV3")
    h = health_until(zsession, "rtkrefused", lambda h: h["state"].get("corrections_state") == "refused")
    assert h["state"]["corrections_refused"] == (
        "model 3151R firmware 2.200 takes RTCM, RTCA "
        "(RTCMV3 carries RTK, which needs the RT-20 or RT-2 option)")
    assert h["errors"]["corrections_refused"] == 1 and h["state"]["receiver_formats"] == ["RTCM", "RTCA"]
    publish(zsession, "rtkrefused", rtcm3(1004), 1)
    fixes = collect(zsession, "viena/rtkrefused/gnss/gnss0/fix", 10, decode=FIX.decode)
    assert len(fixes) == 10 and all(f["valid"] for f in fixes)
    assert "INTERFACEMODE" not in twin.names and not twin.corrections
    procs.stop_all()
    lines = [line for line in log.read_text().splitlines() if " refused: " in line]
    assert len(lines) == 1 and lines[0].endswith(
        "gnss0: corrections RTCMV3 refused: model 3151R firmware 2.200 takes RTCM, RTCA "
        "(RTCMV3 carries RTK, which needs the RT-20 or RT-2 option)"), lines


def test_a_flood_faster_than_the_line_is_dropped_by_whole_frames(procs, zrouter, zsession, receiver, tmp_path):
    """At 9600 baud the corrections may use 864 B/s, a bucket of 1029 bytes: a first sample of
    40 frames (20 kB at one instant) leaves two of them on the line, whatever the machine's
    speed; then more samples: whole frames only, and every byte written or dropped."""
    twin, url = receiver()
    log = tmp_path / "gnss.log"
    gnss(procs, zrouter, "rtkflood", url, log, "--corrections", "RTCMV3", "--baudrate", "9600")
    health_until(zsession, "rtkflood", lambda h: h["state"].get("corrections_state") == "waiting")
    frame = rtcm3(1004, 494)                        # 500 bytes
    publish(zsession, "rtkflood", frame * 40, 0)
    h = health_until(zsession, "rtkflood", lambda h: h["counts"].get("corrections_samples", 0) >= 1)
    assert h["counts"]["corrections_bytes_written"] == 1000                  # the full bucket: two frames
    assert h["errors"]["corrections_dropped_flood"] == 38 * 500
    for seq in range(1, 20):
        publish(zsession, "rtkflood", frame + frame, seq)
    h = health_until(zsession, "rtkflood", lambda h: h["counts"].get("corrections_samples", 0) >= 20)
    written = h["counts"]["corrections_bytes_written"]
    assert written == len(twin.corrections) and written % 500 == 0
    assert written < 40 * 500 + 19 * 1000                                   # the flood is cut
    assert h["errors"]["corrections_dropped_flood"] == 40 * 500 + 19 * 1000 - written
    splitter = Rtcm3Splitter()
    assert len(splitter.feed(bytes(twin.corrections))) == written // 500 and splitter.garbage_bytes == 0
    procs.stop_all()
    assert log.read_text().count("more than the line carries") == 1


def test_a_base_s_rtcm_on_a_second_port_makes_the_fixes_differential(procs, zrouter, zsession, tmp_path):
    """The whole receiver end with real bytes: a simulated base's RTCM 3 (1004/1005, and MSM
    the OEM4 cannot decode) published as the NTRIP client does, written by the service to
    the twin's COM2 (configured through COM1), and the fixes on zenoh turn differential."""
    base_mod = pytest.importorskip("viena.services.ntrip.simulator.base")
    schedule = pytest.importorskip("viena.services.ntrip.simulator.schedule")
    from viena.services.sim.model.truth import IST_ORIGIN

    twin = NovatelTwin(still(), seed=3, outage_interval_s=0.0)
    com1, com2 = SerialEndpoint(twin).start(), SerialEndpoint(twin.port("COM2"), name="com2").start()
    try:
        log = tmp_path / "gnss.log"
        gnss(procs, zrouter, "rtkcom2", com1.url, log, "--corrections", "RTCMV3", "--corrections-port", com2.url)
        h = health_until(zsession, "rtkcom2", lambda h: h["state"].get("corrections_state") == "waiting")
        assert h["state"]["corrections_port"] == com2.url, h["state"]
        assert twin.com2.rxtype.name == "RTCMV3" and twin.com2.baud == 115200
        frames = schedule.Frames(base_mod.BaseStation.at(IST_ORIGIN, baseline_m=800.0, station_id=2050))
        messages = {**schedule.RTK, 1074: 1}
        sent = set()
        got: list = []
        end = time.monotonic() + 20
        while time.monotonic() < end and not any(f["pos_type"] in DIFFERENTIAL for f in got[-5:]):
            gps_s = twin.clock.gps_ms(time.monotonic()) // 1000
            if gps_s not in sent:
                data = b"".join(f for _, f in frames.at(messages, gps_s, first=not sent))
                publish(zsession, "rtkcom2", data, len(sent))
                sent.add(gps_s)
            got += collect(zsession, "viena/rtkcom2/gnss/gnss0/fix", 5, timeout=1.0, decode=FIX.decode)
        differential = [f for f in got if f["pos_type"] in DIFFERENTIAL]
        assert differential and all(f["valid"] for f in differential), {f["pos_type"] for f in got}
        assert all(0 <= f["diff_age_s"] < 3.0 for f in differential)
        assert {f["base_id"] for f in differential} == {"2050"}            # the base's DF003
        h = health_until(zsession, "rtkcom2", lambda h: h["state"].get("solution_kind") not in (None, "single", "sbas"))
        dropped = h["state"]["corrections_dropped_types"]
        assert dropped["1074"] == len(sent) and set(dropped) <= {"1074", "1033"}     # MSM, descriptors
        assert h["counts"]["corrections_bytes_written"] == twin.com2.line.carried > 0
        assert twin.overruns == 0
    finally:
        com1.stop()
        com2.stop()


def gnss_service(*flags: str) -> GnssService:
    """The service as configured by `flags`, not started (no session)."""
    return GnssService(build_parser(GnssService).parse_args(["--port", "socket://127.0.0.1:9", *flags]))


def test_corrections_on_the_logs_port_without_a_break_are_a_config_error():
    """The port takes no commands after INTERFACEMODE until a break: with send_break off the
    receiver would be stranded; the error names the two ways out."""
    with pytest.raises(ConfigError, match="send_break auto or on, or a corrections_port"):
        gnss_service("--corrections", "RTCMV3", "--send-break", "off")
    gnss_service("--corrections", "RTCMV3", "--send-break", "off", "--corrections-port", "socket://127.0.0.1:10")
    gnss_service("--corrections", "RTCMV3")                  # socket:// and auto: a line at start, no error
    gnss_service("--send-break", "off")                      # without corrections: nothing to strand


class UnansweredReceiver:
    """What ReceiverCorrections reads of a receiver whose INTERFACEMODE went unanswered."""

    corrections_refused, corrections_format, corrections_unconfirmed, ability = "", "RTCMV3", True, None

    def write_corrections(self, data: bytes) -> None:
        pass


def test_an_unconfirmed_switch_is_the_state_until_a_fix_is_differential():
    service = gnss_service("--corrections", "RTCMV3")
    corrections = ReceiverCorrections(service, UnansweredReceiver())
    state = lambda: service.health.snapshot()["state"]["corrections_state"]   # noqa: E731
    corrections.started()
    assert state() == "unconfirmed"
    corrections.fix_kind("single")
    corrections._report()
    assert state() == "unconfirmed"
    corrections.fix_kind("float")
    corrections._report()
    assert state() == "waiting"                              # confirmed; no sample yet
    corrections.started()                                    # the next start-up asks again
    assert state() == "unconfirmed"
