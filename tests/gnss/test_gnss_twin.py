"""The NovAtel and NMEA twins, driven by hand on a synthetic clock: responses in the
receiver's format, logs at their triggers, time-correlated noise of the error budget's size
(docs/sensors.md#gnss-error-budget; what the standalone profile adds to it:
test_gnss_twin_errors.py), outages, lever arms."""
from __future__ import annotations

import struct

import numpy as np
import pymap3d
import pytest
from gnss_helpers import HARNESS_GPS_MS, TwinHarness, still

from viena.services.gnss.driver.nmea import NmeaDecoder
from viena.services.gnss.driver.novatel import (
    Com,
    DynamicsCommand,
    Header,
    Log,
    MessageId,
    Port,
    Reset,
    ResponseId,
    SaveConfig,
    SbasControl,
    SbasKeyword,
    Trigger,
    Unlog,
    Unlogall,
    encode_frame,
)
from viena.services.gnss.fixes import fix_from_bestpos, fix_from_bestxyz, fix_from_nmea
from viena.services.gnss.simulator import NmeaTwin, NovatelTwin
from viena.services.gnss.simulator.errors import CEP_PER_SIGMA, GnssErrorModel
from viena.services.sim.model.truth import IST_ORIGIN


def novatel(**kw) -> TwinHarness:
    kw.setdefault("outage_interval_s", 0.0)
    return TwinHarness(NovatelTwin(still(), **kw))


def horizontal_error(ecef) -> float:
    e, n, _ = pymap3d.ecef2enu(*ecef, *IST_ORIGIN)
    return float(np.hypot(e, n))


# -- commands --------------------------------------------------------------------------


@pytest.mark.parametrize("cmd", [
    Unlogall(), Com(baud=115200), DynamicsCommand(0), SbasControl(), SaveConfig(),
    Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05),
    Log(message=MessageId.BESTPOS, trigger=Trigger.ONCE), Reset(0),
], ids=lambda c: c.name)
def test_every_command_is_answered_ok_in_binary(cmd):
    h = novatel()
    response = h.command(cmd)
    assert (response.response_id, response.text) == (ResponseId.OK, "OK")
    header = h.responses[-1][0]
    assert header.message_id == cmd.MESSAGE_ID and header.message_type == 0x82


@pytest.mark.parametrize("frame, answer", [
    # the old library's SBASCONTROL: 16-byte body, header length 0
    (encode_frame(Header(MessageId.SBASCONTROL), b"")[:28] + struct.pack("<4L", 1, 1, 0, 0)
     + b"\0" * 4, (ResponseId.INVALID_CHECKSUM, "INVALID CHECKSUM")),
    (SbasControl(7).frame(), (ResponseId.INVALID_MESSAGE_FIELD, "INVALID MESSAGE. FIELD = 2")),
    (SbasControl(prn=99).frame(), (ResponseId.PARAMETER_OUT_OF_RANGE, "PARAMETER 4 IS OUT OF RANGE")),
    (Com(baud=12345).frame(), (ResponseId.INVALID_BAUD_RATE, "INVALID BAUD RATE")),
    (Log(message=999).frame(), (ResponseId.LOG_DOES_NOT_EXIST, "REQUESTED LOG DOES NOT EXIST")),
    (Log(trigger=Trigger.ONTIME, period=1.0, offset=2.0).frame(), (ResponseId.INVALID_OFFSET, "INVALID OFFSET")),
    (Unlog(message=MessageId.BESTVEL).frame(), (ResponseId.LOG_DOES_NOT_EXIST, "REQUESTED LOG DOES NOT EXIST")),
    (encode_frame(Header(77), b""), (ResponseId.INVALID_MESSAGE_ID, "INVALID MESSAGE ID")),
    (encode_frame(Header(MessageId.DYNAMICS), b"\0\0"), (ResponseId.MESSAGE_MISSING_FIELD, "MESSAGE MISSING FIELD")),
], ids=["old-sbascontrol", "bad-keyword", "bad-prn", "bad-baud", "no-such-log", "bad-offset",
        "unlog-missing", "unknown-id", "short-body"])
def test_bad_commands_get_the_receivers_error(frame, answer):
    h = novatel()
    h.send(frame)
    (header, response), = h.responses
    assert (response.response_id, response.text) == answer
    assert header.is_response


def test_garbage_between_commands_is_skipped():
    h = novatel()
    h.send(b"hello\xaa\x44" + Unlogall().frame() + b"\x00\xaa" + DynamicsCommand(1).frame())
    assert [r.text for _, r in h.responses] == ["OK", "OK"]
    assert h.twin.dynamics == 1


# -- triggers --------------------------------------------------------------------------


def test_ontime_logs_come_on_gps_time_multiples_of_their_period():
    h = novatel()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05))
    h.command(Log(message=MessageId.BESTVEL, trigger=Trigger.ONTIME, period=1.0, offset=0.5))
    h.run(3.0)
    xyz = [m.gps_ms for m in h.logs if m.name == "BESTXYZ"]
    vel = [m.gps_ms for m in h.logs if m.name == "BESTVEL"]
    assert all(ms % 50 == 0 for ms in xyz) and set(np.diff(xyz)) == {50}
    assert len(xyz) == 59                       # 3 s; the epoch at the command came before it
    assert all(ms % 1000 == 500 for ms in vel) and len(vel) == 3


def test_period_below_20_hz_is_raised_to_20_hz():
    h = novatel()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.01))
    h.run(1.0)
    assert set(np.diff([m.gps_ms for m in h.logs])) == {50}


def test_once_onnext_onnew_onchanged():
    h = novatel()
    h.command(Log(message=MessageId.BESTPOS, trigger=Trigger.ONCE))
    assert [m.name for m in h.logs] == ["BESTPOS"]            # at once, after its response
    h.command(Log(message=MessageId.BESTVEL, trigger=Trigger.ONNEXT))
    h.run(1.0)
    assert [m.name for m in h.logs].count("BESTVEL") == 1
    h.logs.clear()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONNEW))
    h.run(1.0)
    assert set(np.diff([m.gps_ms for m in h.logs])) == {50}     # every new solution
    h.command(Unlog(message=MessageId.BESTXYZ))
    h.logs.clear()
    h.command(Log(message=MessageId.BESTPOS, trigger=Trigger.ONCHANGED))
    assert len(h.logs) == 1                                       # the current one at once
    h.run(0.5)
    assert len(h.logs) == 10                                      # then each new one


def test_unlogall_keeps_held_logs_unless_told():
    h = novatel()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.1, hold=1))
    h.command(Log(message=MessageId.BESTVEL, trigger=Trigger.ONTIME, period=0.1))
    h.command(Unlogall(Port.THISPORT_ALL, held=0))
    assert set(h.twin.logs) == {MessageId.BESTXYZ}
    h.command(Unlogall(Port.ALL_PORTS, held=1))
    h.logs.clear()
    h.run(0.5)
    assert h.twin.logs == {} and h.logs == []


def test_reset_restores_the_saved_configuration_after_a_cold_start():
    h = novatel(boot_s=1.0, reset_cold_start_s=2.0)
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.5))
    h.command(SaveConfig())
    h.command(Unlogall())
    h.command(Reset(0))
    h.logs.clear()
    h.run(0.9)
    assert h.logs == []                                           # booting: silent
    h.run(5.0)
    statuses = [(m.header.time_status, m.data.pos_status.name) for m in h.logs]
    assert statuses[0] == (20, "INSUFFICIENT_OBS")                # UNKNOWN time, no fix
    assert statuses[-1] == (180, "SOL_COMPUTED")
    assert h.logs[0].data.position_m == (100.0, 0.0, 0.0)
    assert h.logs[0].gps_week == 0


def test_sbascontrol_enable_is_zero_and_gives_sbas_solutions():
    h = novatel()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.1))
    h.run(0.3)
    assert h.logs[-1].data.pos_type.name == "SINGLE"
    h.command(SbasControl(SbasKeyword.ENABLE))
    h.run(0.3)
    assert h.logs[-1].data.pos_type.name == "WAAS"
    h.command(SbasControl(SbasKeyword.DISABLE))
    h.run(0.3)
    assert h.logs[-1].data.pos_type.name == "SINGLE"


def test_a_new_connection_resets_the_port_like_a_break():
    h = novatel()
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.1))
    h.command(Log(message=MessageId.BESTVEL, trigger=Trigger.ONTIME, period=0.1, hold=1))
    h.command(Com(baud=115200))
    assert h.twin.baud == 115200
    h.twin.on_connect(h.now)
    assert set(h.twin.logs) == {MessageId.BESTVEL} and h.twin.baud == 9600


# -- solutions -------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["gauss_markov", "standalone"])
def test_noise_is_seed_table_sized_about_1_8_m_cep(profile):
    errors = []
    for seed in range(300):
        model = GnssErrorModel(np.random.default_rng(seed), cep_m=1.8, profile=profile)
        pos, _ = model.step(0.0)
        errors.append(np.hypot(pos[0], pos[1]))
    assert np.median(errors) == pytest.approx(1.8, rel=0.12)
    sigma = GnssErrorModel(np.random.default_rng(0), profile=profile).sigma_enu
    if profile == "gauss_markov":       # a Gaussian: the sigma is the CEP's
        assert sigma[0] * CEP_PER_SIGMA == pytest.approx(1.8)
    else:                               # heavier tails: a larger RMS for the same CEP
        assert sigma[0] * CEP_PER_SIGMA == pytest.approx(1.8, rel=0.1) and sigma[0] * CEP_PER_SIGMA > 1.8
    assert sigma[2] > sigma[0]                                    # vertical is worse


def test_noise_is_time_correlated():
    """The wander alone (the standalone profile adds steps and outliers:
    test_gnss_twin_errors.py)."""
    model = GnssErrorModel(np.random.default_rng(4), profile="gauss_markov")
    track = np.array([model.step(0.05 * k)[0] for k in range(200)])
    steps = np.linalg.norm(np.diff(track, axis=0), axis=1)
    assert np.max(steps) < 0.5                                    # no jumps between epochs
    assert np.linalg.norm(track[0]) > 5 * np.mean(steps)          # a wander, not white noise


def test_fixes_are_within_noise_of_the_antenna():
    h = novatel(seed=11, lever_arm_m=(0.0, 2.0, 1.5))
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.05))
    h.run(2.0)
    antenna = np.array(pymap3d.enu2ecef(0.0, 2.0, 1.5, *IST_ORIGIN))   # yaw 0: y is north
    for msg in h.logs:
        fix = fix_from_bestxyz(msg, "gnss0", 0)
        assert fix["valid"]
        err = np.array(fix["ecef_m"]) - antenna
        assert np.linalg.norm(err) < 4 * np.linalg.norm(fix["ecef_sigma_m"])


def test_lever_arms_separate_two_antennas():
    a = novatel(seed=1, cep_m=1e-6, lever_arm_m=(-0.5, 1.0, 1.5))
    b = novatel(seed=1, cep_m=1e-6, lever_arm_m=(0.5, 1.0, 1.5))
    for h in (a, b):
        h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONCE))
    d = np.array(b.logs[0].data.position_m) - np.array(a.logs[0].data.position_m)
    e, n, u = pymap3d.uvw2enu(*d, IST_ORIGIN[0], IST_ORIGIN[1])
    assert (e, n, u) == pytest.approx((1.0, 0.0, 0.0), abs=1e-3)   # x right = east at yaw 0


def test_outage_holds_the_last_fix_then_reports_no_fix():
    h = novatel(outages=[(1.0, 6.0)])
    h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=0.5))
    h.run(8.0)
    data = [m.data for m in h.logs]
    status = [d.pos_status.name for d in data]
    assert status[0] == "SOL_COMPUTED" and status[-1] == "SOL_COMPUTED"
    out = [d for d in data if d.pos_status.name == "INSUFFICIENT_OBS"]
    assert len(out) == 10
    held = [d for d in out if d.position_m != (100.0, 0.0, 0.0)]
    assert held and all(d.sol_age_s > 0 and d.sats_used < 4 for d in held)
    assert held[0].position_m == data[status.index("INSUFFICIENT_OBS") - 1].position_m
    nofix = [d for d in out if d.position_m == (100.0, 0.0, 0.0)]
    assert nofix and all(d.pos_type.name == "NONE" for d in nofix)
    fixes = [fix_from_bestxyz(m, "gnss0", 0) for m in h.logs]
    assert [f["valid"] for f in fixes].count(False) == 10


def test_bestpos_and_bestvel_agree_with_bestxyz():
    h = novatel(seed=2)
    for message in (MessageId.BESTXYZ, MessageId.BESTPOS, MessageId.BESTVEL):
        h.command(Log(message=message, trigger=Trigger.ONTIME, period=0.2))
    h.run(1.0)
    by_epoch: dict = {}
    for m in h.logs:
        by_epoch.setdefault(m.gps_ms, {})[m.name] = m
    for logs in by_epoch.values():
        xyz = fix_from_bestxyz(logs["BESTXYZ"], "u", 0)
        pos = fix_from_bestpos(logs["BESTPOS"], logs["BESTVEL"], "u", 0)
        assert pos["ecef_m"] == pytest.approx(xyz["ecef_m"], abs=1e-6)
        # 10 um: the two heights come by different conversions (ecef -> geodetic, and
        # BESTPOS's MSL height + undulation); their rounding differs by ~1 um on some runs
        assert pos["height_m"] == pytest.approx(xyz["height_m"], abs=1e-5)
        assert pos["vel_ecef_mps"] == pytest.approx(xyz["vel_ecef_mps"], abs=1e-6)
        assert pos["ecef_sigma_m"] == pytest.approx(xyz["ecef_sigma_m"], rel=1e-3)


# -- NMEA ------------------------------------------------------------------------------


def test_nmea_twin_streams_10_hz_epochs_within_noise():
    twin = NmeaTwin(still(), seed=3, lever_arm_m=(0.0, 1.0, 1.4), outage_interval_s=0.0)
    decoder = NmeaDecoder()
    now, fixes = 50.0, []
    twin.clock.anchor(now, HARNESS_GPS_MS)
    twin.on_connect(now)
    while now < 52.0:
        now = min(52.0, max(now + 1e-4, twin.next_due(now)))
        fixes += decoder.feed(twin.poll(now), 0)
    assert decoder.stats.checksum_errors == decoder.stats.parse_errors == 0
    assert len(fixes) == 21          # 2 s, and the epoch already running at the connection
    assert set(np.diff([f.utc_ns for f in fixes])) == {100_000_000}
    assert set(fixes[0].sentences) == {"RMC", "VTG", "GGA", "GSA", "GSV"}
    for fix in fixes:
        sample = fix_from_nmea(fix, "gps0", 0)
        assert sample["valid"] and sample["pos_type"] == "SINGLE"
        assert horizontal_error(sample["ecef_m"]) < 2.5 * 3


def test_nmea_outage_is_quality_zero_and_no_fix_sample():
    twin = NmeaTwin(still(), outages=[(0.0, 10.0)])
    decoder = NmeaDecoder()
    twin.on_connect(0.0)
    fixes = decoder.feed(twin.poll(0.0) + twin.poll(0.5), 0)
    assert fixes and all(f.quality == 0 and f.lat_deg is None for f in fixes)
    assert fix_from_nmea(fixes[0], "gps0", 0) is None
