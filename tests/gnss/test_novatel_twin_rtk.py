"""The NovAtel twin fed real RTCM 3 bytes (the caster twin's base station and encoder) on a
port in RTCMV3 mode: the types its BESTXYZ/BESTPOS go through, COM2 beside COM1, what it
skips (MSM, garbage), what the line loses, VERSION, and the same bytes as before when no
corrections come. Driven by hand on a synthetic clock (TwinHarness)."""
from __future__ import annotations

import collections
from types import SimpleNamespace

import numpy as np
import pymap3d
import pytest
from gnss_helpers import HARNESS_GPS_MS, TwinHarness, still
from pyrtcm.rtcmhelpers import calc_crc24q

from viena.services.gnss.driver.novatel import (
    Com,
    ComPort,
    DgpsTimeout,
    DgpsType,
    FrameDecoder,
    InterfaceMode,
    InterfaceModeCommand,
    Log,
    MessageFormat,
    MessageId,
    Port,
    PositionType,
    PsrDiffSource,
    Reset,
    ResponseId,
    Responses,
    SaveConfig,
    Trigger,
    Unlogall,
    decode_version,
)
from viena.services.gnss.simulator import CommonErrors, NovatelTwin, make_novatel_device
from viena.services.gnss.simulator.ports import Line
from viena.services.gnss.simulator.rtcm_in import RtcmInput
from viena.services.gnss.simulator.rtk import RT20, RtkFigures
from viena.services.ntrip.simulator import base, rtcm, schedule
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import IST_ORIGIN

#: fixes take exactly 10 s + 1 s/km after the float starts, never wrong
QUICK = RtkFigures(fix_mean_s=10.0, fix_s_per_km=1.0, fix_spread=0.0, wrong_fix_chance=0.0,
                   wrong_fix_chance_per_km=0.0)
G0 = HARNESS_GPS_MS // 1000
RTCMV3_ON_COM2 = InterfaceModeCommand(ComPort.COM2, InterfaceMode.RTCMV3, InterfaceMode.NONE, Responses.OFF)


def receiver(**kw) -> TwinHarness:
    kw.setdefault("outage_interval_s", 0.0)
    kw.setdefault("rtk_figures", QUICK)
    return TwinHarness(NovatelTwin(kw.pop("truth", still()), **kw))


def base_stream(seconds: int, baseline_m: float = 1000.0, messages=schedule.RTK, station_id: int = 7) -> dict:
    """What a base `baseline_m` away sends each GPS second from the harness's start: {second: bytes}."""
    station = base.BaseStation.at(IST_ORIGIN, baseline_m, 30.0, station_id=station_id)
    blobs: dict[int, bytes] = collections.defaultdict(bytes)
    for second, _, frame in schedule.stream(station, G0 + 1, seconds, messages):
        blobs[second - G0] += frame
    return blobs


def feed(h: TwinHarness, port, blobs: dict, seconds: int, latency_s: float = 0.3) -> None:
    """Each second's bytes written `latency_s` after its epoch, the clock run in between."""
    start = h.now
    for k in range(1, seconds + 1):
        h.run(start + k + latency_s - h.now)
        if blobs.get(k):
            port.feed(blobs[k], h.now)
    h.run(1.0)


def logs_of(h: TwinHarness, message=MessageId.BESTXYZ) -> list:
    return [m for m in h.logs if m.header.message_id == message]


def types_in_order(logs) -> list[str]:
    out: list[str] = []
    for m in logs:
        name = m.data.pos_type.name
        if not out or out[-1] != name:
            out.append(name)
    return out


def horizontal_error(ecef) -> float:
    e, n, _ = pymap3d.ecef2enu(*ecef, *IST_ORIGIN)
    return float(np.hypot(e, n))


def with_com2_corrections(h: TwinHarness, baud: int = 115200):
    assert h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=1.0)).ok
    assert h.command(Com(ComPort.COM2, baud)).ok
    assert h.command(RTCMV3_ON_COM2).ok
    com2 = h.twin.port("COM2")
    com2.on_connect(h.now)
    return com2


# -- the types -----------------------------------------------------------------------------------


def test_rtcmv3_on_the_logs_port_moves_through_the_types_and_takes_no_more_commands():
    h = receiver()
    assert h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=1.0)).ok
    assert h.command(InterfaceModeCommand(ComPort.THISPORT, InterfaceMode.RTCMV3, InterfaceMode.NOVATEL,
                                          Responses.ON)).ok
    h.send(Unlogall().frame())                          # a port in RTCMV3 takes no commands
    assert len(h.responses) == 2
    feed(h, h.twin, base_stream(30), 30)
    fixes = logs_of(h)
    assert types_in_order(fixes) == ["SINGLE", "PSRDIFF", "NARROW_FLOAT", "NARROW_INT"]
    fixed = [m.data for m in fixes if m.data.pos_type == PositionType.NARROW_INT]
    assert len(fixed) >= 5
    assert all(d.station_id == "7" and d.diff_age_s == pytest.approx(1.0, abs=0.05) for d in fixed)
    assert all(d.sats_l1_rtk == d.sats_l2_rtk == d.sats_used > 0 for d in fixed)
    assert h.twin.rtcm_ignored[1033] >= 1               # the descriptors: not for this firmware
    h.twin.on_connect(h.now)                            # the driver's break: NOVATEL NOVATEL again
    assert h.command(Log(message=MessageId.BESTPOS, trigger=Trigger.ONCE)).ok


def test_com2_takes_corrections_while_com1_carries_commands_and_logs():
    h = receiver()
    com2 = with_com2_corrections(h)
    feed(h, com2, base_stream(25, baseline_m=2000.0), 25)
    assert types_in_order(logs_of(h))[-1] == "NARROW_INT"
    assert com2.poll(h.now) == b""                      # responses OFF, transmits nothing
    assert h.command(Log(message=MessageId.BESTPOS, trigger=Trigger.ONCE)).ok
    pos = logs_of(h, MessageId.BESTPOS)[-1].data
    assert pos.pos_type == PositionType.NARROW_INT and pos.station_id == "7" and pos.diff_age_s > 0
    assert h.twin.overruns == 0 and h.twin.rtcm_crc_errors == 0
    health = h.twin.corrections_health()
    assert health["corrections_read"] == 25 and health["solution"] == "fixed" and health["base_id"] == "7"
    assert 0.3 <= health["correction_age_p50_s"] <= health["correction_age_p95_s"] < 0.4


def test_the_sim_serves_com2_when_configured():
    service = SimpleNamespace(settings=SimpleNamespace(seed=2, host="127.0.0.1"), args=SimpleNamespace(config="sim.toml"))
    car = SimCar()
    devices = [make_novatel_device("gnss0", {"com2_port": 0, "model": "RT20"}, car, service),
               make_novatel_device("gnss1", {}, car, service)]
    try:
        assert set(devices[0].urls) == {"COM1", "COM2"} and len(set(devices[0].urls.values())) == 2
        assert devices[0].twin.engine == RT20 and devices[0].health() == {}
        assert set(devices[1].urls) == {"COM1"} and devices[1].twin.version.model == "RT2WA"
    finally:
        for d in devices:
            d.stop()


def test_com2_takes_commands_until_told_otherwise():
    h = receiver()
    com2 = h.twin.port("COM2")
    com2.on_connect(h.now)
    com2.feed(DgpsTimeout(60).frame(), h.now)
    frames = FrameDecoder().feed(com2.poll(h.now))
    assert len(frames) == 1 and frames[0].header.is_response and frames[0].header.port_address == Port.COM2
    assert h.twin.dgps_timeout_s == 60.0


def test_the_sigma_shrinks_with_each_type_and_each_step_is_real():
    h = receiver(seed=5)
    com2 = with_com2_corrections(h)
    feed(h, com2, base_stream(40), 40)
    by_type: dict[str, list] = collections.defaultdict(list)
    for m in logs_of(h):
        by_type[m.data.pos_type.name].append(m.data)
    sigma = {k: np.mean([np.linalg.norm(d.position_sigma_m) for d in v]) for k, v in by_type.items()}
    assert sigma["SINGLE"] > sigma["PSRDIFF"] > sigma["NARROW_FLOAT"] > sigma["NARROW_INT"]
    assert sigma["NARROW_INT"] < 0.06 and 0.2 < sigma["PSRDIFF"] < 2.0
    error = {k: max(horizontal_error(d.position_m) for d in v) for k, v in by_type.items()}
    assert error["NARROW_INT"] < 0.1
    single, dgps = by_type["SINGLE"][-1], by_type["PSRDIFF"][0]
    step = np.linalg.norm(np.subtract(single.position_m, dgps.position_m))
    assert step > 0.3                                   # the sky's error goes at once


def test_l1_observables_float_on_l1_and_a_dgps_only_model_stays_at_psrdiff():
    h = receiver()
    feed(h, with_com2_corrections(h), base_stream(30, messages=schedule.L1), 30)
    assert types_in_order(logs_of(h)) == ["SINGLE", "PSRDIFF", "L1_FLOAT"]
    h = receiver(model="3151R")
    feed(h, with_com2_corrections(h), base_stream(30), 30)
    assert types_in_order(logs_of(h)) == ["SINGLE", "PSRDIFF"]


def test_a_base_100_km_away_floats():
    h = receiver(rtk_figures=RtkFigures())
    feed(h, with_com2_corrections(h), base_stream(60, baseline_m=100_000.0), 60)
    assert types_in_order(logs_of(h)) == ["SINGLE", "PSRDIFF", "NARROW_FLOAT"]


def test_back_to_single_after_the_timeouts_when_corrections_stop():
    h = receiver()
    com2 = with_com2_corrections(h)
    assert h.command(DgpsTimeout(10)).ok
    feed(h, com2, base_stream(20), 20)
    h.run(70.0)
    fixes = logs_of(h)
    assert types_in_order(fixes)[-3:] == ["NARROW_INT", "NARROW_FLOAT", "SINGLE"]
    last_epoch_ms = (G0 + 20) * 1000 % 604_800_000
    after = [m for m in fixes if m.header.milliseconds > last_epoch_ms]
    fixed_until = max(m.header.milliseconds for m in after if m.data.pos_type == PositionType.NARROW_INT)
    single = next(m for m in after if m.data.pos_type == PositionType.SINGLE)
    assert fixed_until - last_epoch_ms == 30_000        # the ambiguities kept for 30 s
    assert single.header.milliseconds - last_epoch_ms == 61_000     # RTK's 60 s; DGPSTIMEOUT 10 s is past
    assert single.data.station_id == "" and single.data.diff_age_s == 0.0


def test_a_new_psrdiffsource_drops_the_corrections_at_once():
    h = receiver()
    com2 = with_com2_corrections(h)
    feed(h, com2, base_stream(8), 8)
    assert logs_of(h)[-1].data.pos_type != PositionType.SINGLE
    assert h.command(PsrDiffSource(DgpsType.RTCMV3, "8")).ok      # another base
    h.run(1.5)
    assert logs_of(h)[-1].data.pos_type == PositionType.SINGLE


# -- what it skips, what the line loses ------------------------------------------------------------


def test_msm_is_ignored_and_counted():
    h = receiver()
    feed(h, with_com2_corrections(h), base_stream(12, messages=schedule.MSM), 12)
    assert types_in_order(logs_of(h)) == ["SINGLE"]
    assert h.twin.rtcm_ignored[1074] == 12 and h.twin.rtcm_ignored[1084] == 12
    assert h.twin.rover is not None and h.twin.rover.bases     # 1006 was read: it is an OEM4 message


def test_garbage_between_frames_is_skipped():
    h = receiver()
    blobs = {k: b"\xd3\x00\x05garbage" + v + bytes(range(40)) for k, v in base_stream(20).items()}
    feed(h, with_com2_corrections(h), blobs, 20)
    assert types_in_order(logs_of(h))[-1] == "NARROW_INT"
    assert h.twin.rtcm_crc_errors >= 20


def test_a_crc_valid_frame_pyrtcm_cannot_parse_is_skipped_and_counted():
    """A broken base's 1005 cut short (its CRC checks): pyrtcm raises on it; the twin's
    input counts it as malformed and goes on to the next frame."""
    payload = bytes([0x3E, 0xD8, 0x02])                  # DF002 = 1005, DF003 = 2, and no more
    head = bytes([0xD3, 0x00, len(payload)])
    short = head + payload + calc_crc24q(head + payload).to_bytes(3, "big")
    good = rtcm.arp(1005, 2050, (4918528.0, -791210.0, 3969759.0))
    reader = RtcmInput()
    got = reader.feed(short + good)
    assert [m.base_id for m in got] == ["2050"]
    assert reader.malformed == {1005: 1} and reader.decoded == {1005: 1} and reader.frames == 2


def test_bytes_arrive_at_the_baud_and_more_than_the_line_carries_is_lost():
    line = Line(buffer_bytes=4096)
    line.send(bytes(1000), 0.0, 9600)
    assert len(line.receive(0.5)) == 480 and len(line.receive(1.0)) == 480
    line.send(bytes(10_000), 1.0, 9600)                  # 40 bytes still on the line
    assert line.overruns == 10_000 - (4096 - 40)
    h = receiver()
    com2 = with_com2_corrections(h, baud=9600)
    blobs = base_stream(12)
    assert rtcm.message_number(blobs[2]) == 1004        # second 2: the observables alone
    feed(h, com2, blobs, 12, latency_s=0.1)
    ages = h.twin.correction_ages_s
    assert len(ages) == 12 and min(ages) == pytest.approx(0.1 + len(blobs[2]) * 10 / 9600, abs=0.01)
    com2.feed(bytes(20_000), h.now)
    assert h.twin.overruns > 15_000


# -- VERSION, and the bytes without corrections ------------------------------------------------------


@pytest.mark.parametrize("model, firmware", [("RT2WA", "2.310"), ("3151R", "2.200A1")])
def test_version_says_the_model_and_firmware(model, firmware):
    h = receiver(model=model, firmware=firmware)
    h.twin.feed(Log(message=MessageId.VERSION, trigger=Trigger.ONCE).frame(), h.now)
    response, version = FrameDecoder().feed(h.twin.poll(h.now))
    assert response.header.is_response and version.header.message_id == MessageId.VERSION
    card = decode_version(version).card
    assert (card.model, card.sw_version, card.hw_version) == (model, firmware, "OEM4g2-2.00-X2T")
    ontime = h.command(Log(message=MessageId.VERSION, trigger=Trigger.ONTIME, period=1.0))
    assert ontime.response_id == ResponseId.TRIGGER_NOT_VALID


def bestxyz_bytes(configure) -> bytes:
    twin = NovatelTwin(still(), seed=3, outage_interval_s=20.0)
    h = TwinHarness(twin)
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05))
    configure(h)
    out = bytearray()
    for _ in range(300):
        h.now += 0.1
        out += twin.poll(h.now)
    return b"".join(f.body for f in FrameDecoder().feed(bytes(out)) if f.header.message_id == MessageId.BESTXYZ)


def test_without_corrections_the_fixes_are_the_same_bytes_as_before():
    plain = bestxyz_bytes(lambda h: None)

    def msm_only(h):                                     # told of corrections, given none it can use
        assert h.command(RTCMV3_ON_COM2).ok
        h.twin.port("COM2").feed(b"".join(base_stream(3, messages=schedule.MSM).values()), h.now)
    assert bestxyz_bytes(msm_only) == plain and len(plain) > 50_000      # 30 s at 20 Hz


def test_two_receivers_share_the_base_and_the_sky():
    """At 20 km the fixed solutions' error is mostly the baseline's, the same for both."""
    sky = CommonErrors(np.random.default_rng(1))
    blobs = base_stream(60, baseline_m=20_000.0)
    errors = []
    for seed in (3, 4):
        h = receiver(seed=seed, common_errors=sky)
        feed(h, with_com2_corrections(h), blobs, 60)
        fixed = {m.header.milliseconds: np.array(pymap3d.ecef2enu(*m.data.position_m, *IST_ORIGIN))
                 for m in logs_of(h) if m.data.pos_type == PositionType.NARROW_INT}
        errors.append(fixed)
    both = sorted(set(errors[0]) & set(errors[1]))
    assert len(both) >= 20
    a, b = (np.array([e[t] for t in both]) for e in errors)
    rms = lambda v: float(np.sqrt(np.mean(np.sum(v[:, :2] ** 2, axis=1))))  # noqa: E731
    assert rms(a - b) < 0.5 * min(rms(a), rms(b))


def test_rxconfig_lists_the_corrections_settings_and_saveconfig_keeps_them():
    h = receiver()
    for cmd in (Com(ComPort.COM2, 115200), RTCMV3_ON_COM2, DgpsTimeout(60), PsrDiffSource(DgpsType.RTCMV3, "7")):
        assert h.command(cmd).ok
    h.twin.feed(Log(message=MessageId.RXCONFIG, message_type=MessageFormat.ASCII << 5, trigger=Trigger.ONCE).frame(),
                h.now)
    text = "\n".join(f.text for f in FrameDecoder().feed(h.twin.poll(h.now)) if hasattr(f, "text"))
    for line in ("#INTERFACEMODEA", ";COM2,RTCMV3,NONE,OFF", ";COM2,115200,N,8,1,N,OFF,ON", "#DGPSTIMEOUTA",
                 ';RTCMV3,"7"'):
        assert line in text
    assert h.command(SaveConfig()).ok and h.command(Reset(0)).ok
    h.run(3.0)
    com2 = h.twin.com2
    assert (com2.rxtype, com2.baud, h.twin.dgps_timeout_s) == (InterfaceMode.RTCMV3, 115200, 60.0)
