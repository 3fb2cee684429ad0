"""The caster twin's RTCM 3: every message built from fields parses back, by pyrtcm, to those
fields; the base station's measurements are honest geometry; the schedule sends what the
source table says. (services/ntrip/simulator: rtcm.py, sky.py, base.py, schedule.py)"""
from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymap3d import vincenty
from pyrtcm import RTCMMessage, RTCMReader
from pyrtcm.rtcmtypes_core import RTCM_DATA_FIELDS

from viena.services.gnss.driver.gpstime import GPS_EPOCH_UNIX_S, leap_seconds_at_gps
from viena.services.ntrip.simulator import rtcm, schedule, sky
from viena.services.ntrip.simulator.base import BaseStation, place
from viena.services.sim.model.truth import IST_ORIGIN

#: a whole GPS second in 2026 (any will do; the tests must not depend on the wall clock)
T0 = 1_451_000_000
ARP = (4_918_525.1234, -791_212.5678, 3_969_762.4321)


def parse(frame: bytes) -> RTCMMessage:
    """pyrtcm's parse with the CRC checked."""
    return RTCMReader.parse(frame, validate=1)


def assert_fields(parsed: RTCMMessage, values: dict) -> None:
    """Every field built is parsed back, to its resolution."""
    for name, value in values.items():
        got = getattr(parsed, name)
        scale = RTCM_DATA_FIELDS[name.split("_")[0]][2]
        if isinstance(value, str):
            assert got == value, name
        elif scale in (0, 1):
            assert got == value, name
        else:
            assert got == pytest.approx(value, abs=scale / 2 + 1e-9), name


# -- the generic encoder -------------------------------------------------------------------------------
def test_a_1005_built_from_fields_parses_back_to_them():
    values = {"DF003": 2047, "DF021": 0, "DF022": 1, "DF023": 0, "DF024": 0, "DF141": 0,
              "DF025": ARP[0], "DF142": 1, "DF026": ARP[1], "DF364": 0, "DF027": ARP[2]}
    frame = rtcm.message(1005, values)
    parsed = parse(frame)
    assert parsed.identity == "1005" and rtcm.message_number(frame) == 1005
    assert_fields(parsed, values)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 63), st.integers(0, 2**24 - 1), st.integers(-2**19, 2**19 - 1),
                          st.integers(0, 127), st.integers(0, 255), st.integers(0, 255), st.integers(0, 3),
                          st.integers(-2**13, 2**13 - 1), st.integers(-2**19, 2**19 - 1), st.integers(0, 127),
                          st.integers(0, 255)), min_size=0, max_size=20),
       st.integers(0, 4095), st.integers(0, 604_799_999), st.booleans())
def test_any_1004_built_from_fields_parses_back_to_them(sats, station, tow, more):
    """Fields drawn over their whole ranges, signed ones at both ends: the bits land where
    pyrtcm reads them."""
    values = {"DF003": station, "DF004": tow, "DF005": int(more), "DF006": len(sats), "DF007": 0, "DF008": 0}
    for i, (prn, pr, ph, lock, amb, cnr, code2, dpr, ph2, lock2, cnr2) in enumerate(sats, 1):
        values.update({f"DF009_{i:02d}": prn, f"DF010_{i:02d}": 0, f"DF011_{i:02d}": pr * 0.02,
                       f"DF012_{i:02d}": ph * 0.0005, f"DF013_{i:02d}": lock, f"DF014_{i:02d}": amb,
                       f"DF015_{i:02d}": cnr * 0.25, f"DF016_{i:02d}": code2, f"DF017_{i:02d}": dpr * 0.02,
                       f"DF018_{i:02d}": ph2 * 0.0005, f"DF019_{i:02d}": lock2, f"DF020_{i:02d}": cnr2 * 0.25})
    assert_fields(parse(rtcm.message(1004, values)), values)


def test_a_field_out_of_its_range_or_missing_is_refused():
    with pytest.raises(rtcm.EncodeError, match="DF003"):
        rtcm.message(1005, {"DF003": 4096})
    with pytest.raises(rtcm.EncodeError, match="DF025"):
        rtcm.message(1005, {"DF003": 1, "DF021": 0, "DF022": 1, "DF023": 0, "DF024": 0, "DF141": 0})
    with pytest.raises(rtcm.EncodeError, match="no definition"):
        rtcm.message(9999, {})


# -- the messages of a base --------------------------------------------------------------------------------
@pytest.mark.parametrize("number", [1005, 1006])
def test_the_antenna_reference_point(number):
    parsed = parse(rtcm.arp(number, 1234, ARP, 1.5))
    assert (parsed.DF002, parsed.DF003, parsed.DF022) == (number, 1234, 1)
    assert (parsed.DF025, parsed.DF026, parsed.DF027) == pytest.approx(ARP, abs=5e-5)
    if number == 1006:
        assert parsed.DF028 == pytest.approx(1.5)


def test_the_descriptors():
    d = rtcm.Descriptors(antenna="TRM57971.00     NONE", antenna_serial="1441", receiver="NOVATEL OEM7",
                         firmware="7.08", receiver_serial="BFN123")
    parsed = parse(rtcm.descriptors(77, d))
    text = lambda name, count: "".join(getattr(parsed, f"{name}_{i:02d}") for i in range(1, count + 1))  # noqa: E731
    assert parsed.DF003 == 77
    assert text("DF030", parsed.DF029) == d.antenna
    assert text("DF033", parsed.DF032) == d.antenna_serial
    assert text("DF228", parsed.DF227) == d.receiver
    assert text("DF230", parsed.DF229) == d.firmware
    assert text("DF232", parsed.DF231) == d.receiver_serial


def signals(sat, pr, phase_offset, lock_s=400.0):
    return rtcm.SatSignals(sat, {1: rtcm.Signal(pr, pr + phase_offset, lock_s, 45.0),
                                 2: rtcm.Signal(pr + 3.1, pr - phase_offset, lock_s, 39.0)})


@pytest.mark.parametrize("number", [1002, 1004])
def test_legacy_observables_give_back_the_ranges(number):
    """The rover rebuilds the L1 pseudorange from its modulus and integer milliseconds, the
    phase ranges from their differences: to the fields' 0.02 m and 0.5 mm."""
    sats = [signals(5, 21_000_123.456, 31.7), signals(12, 23_500_000.5, -120.25, 10.0), signals(29, 25_999_999.99, 0.0)]
    parsed = parse(rtcm.legacy_observables(number, 9, 345_600_000, sats))
    assert (parsed.DF003, parsed.DF004, parsed.DF006) == (9, 345_600_000, 3)
    for i, s in enumerate(sats, 1):
        pr = getattr(parsed, f"DF014_{i:02d}") * rtcm.LIGHT_MS_M + getattr(parsed, f"DF011_{i:02d}")
        assert getattr(parsed, f"DF009_{i:02d}") == s.sat
        assert pr == pytest.approx(s.bands[1].pseudorange_m, abs=0.01)
        assert pr + getattr(parsed, f"DF012_{i:02d}") == pytest.approx(s.bands[1].phase_range_m, abs=0.011)
        assert getattr(parsed, f"DF013_{i:02d}") == rtcm.legacy_lock_indicator(s.bands[1].lock_s)
        if number == 1004:
            assert pr + getattr(parsed, f"DF017_{i:02d}") == pytest.approx(s.bands[2].pseudorange_m, abs=0.02)
            assert pr + getattr(parsed, f"DF018_{i:02d}") == pytest.approx(s.bands[2].phase_range_m, abs=0.011)
            assert getattr(parsed, f"DF020_{i:02d}") == 39.0


@pytest.mark.parametrize(("number", "epoch", "signal_ids"),
                         [(1074, {"DF004": 345_600_000}, rtcm.GPS_SIGNALS),
                          (1084, {"DF416": 3, "DF034": 45_000_000}, rtcm.GLONASS_SIGNALS)])
def test_msm4_gives_back_the_ranges(number, epoch, signal_ids):
    sats = [signals(5, 21_000_123.456, 31.7), signals(12, 23_500_000.5, -120.25), signals(3, 19_100_000.0, 7.0)]
    parsed = parse(rtcm.msm4(number, 9, epoch, sats, signal_ids, more=True))
    assert (parsed.DF003, parsed.DF393, parsed.NSat, parsed.NSig, parsed.NCell) == (9, 1, 3, 2, 6)
    for key, value in epoch.items():
        assert getattr(parsed, key) == value
    ranges = rtcm.msm_ranges(parsed)
    codes = {1: "1C", 2: "2W" if number == 1074 else "2P"}
    for s in sats:
        for band, sig in s.bands.items():
            pr, phase = ranges[(s.sat, codes[band])]
            assert pr == pytest.approx(sig.pseudorange_m, abs=0.01)          # 2**-24 ms = 1.8 cm steps
            assert phase == pytest.approx(sig.phase_range_m, abs=0.001)      # 2**-29 ms = 0.6 mm steps


@pytest.mark.parametrize(("lock_s", "indicator"), [(0, 0), (23, 23), (24, 24), (71, 47), (72, 48), (167, 71),
                                                   (168, 72), (359, 95), (360, 96), (743, 119), (744, 120),
                                                   (936, 126), (937, 127), (10_000, 127)])
def test_the_legacy_lock_time_indicator_follows_the_standards_table(lock_s, indicator):
    assert rtcm.legacy_lock_indicator(lock_s) == indicator


@pytest.mark.parametrize(("lock_s", "indicator"), [(0.0, 0), (0.031, 0), (0.032, 1), (0.064, 2), (1.0, 5),
                                                   (524.288, 15), (10_000.0, 15)])
def test_the_msm_lock_time_indicator(lock_s, indicator):
    assert rtcm.msm_lock_indicator(lock_s) == indicator


# -- the sky -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("constellation", [sky.GPS, sky.GLONASS], ids=["GPS", "GLONASS"])
def test_orbits_are_circular_and_their_ground_tracks_repeat(constellation):
    radius = {"GPS": 26_561.7e3, "GLO": 25_510e3}[constellation.system]
    days = {"GPS": 1, "GLO": 8}[constellation.system]
    r = constellation.ecef_m(T0)
    assert np.linalg.norm(r, axis=1) == pytest.approx(radius, rel=2e-4)
    repeat = days * 2 * math.pi / (sky.OMEGA_E_RADPS - constellation.node_rate_radps)
    assert np.abs(constellation.ecef_m(T0 + repeat) - r).max() < 1.0
    inclination = math.degrees(math.asin(np.abs(constellation.ecef_m(np.arange(T0, T0 + 43_200, 60))[..., 2]).max() / radius))
    assert inclination == pytest.approx({"GPS": 55.0, "GLO": 64.8}[constellation.system], abs=0.1)


def test_a_base_at_lisbon_sees_what_the_24_slot_constellation_gives():
    base = BaseStation(*IST_ORIGIN)
    counts = [len(base.visible("GPS", T0 + k * 300)) for k in range(288)]        # a day
    assert 4 <= min(counts) and max(counts) <= 12 and 6 <= np.mean(counts) <= 8
    assert len({s for k in range(0, 288, 6) for s, _, _ in base.visible("GPS", T0 + k * 300)}) == 24


# -- the base --------------------------------------------------------------------------------------------
def test_the_base_stands_at_its_baseline():
    base = BaseStation.at(IST_ORIGIN, 200_000.0, 30.0)
    lat, lon, h = base.position
    distance, azimuth = vincenty.vdist(IST_ORIGIN[0], IST_ORIGIN[1], lat, lon)
    assert float(distance) == pytest.approx(200_000.0, abs=1e-3)
    assert float(azimuth) == pytest.approx(30.0, abs=1e-6)
    assert h == IST_ORIGIN[2]
    assert base.baseline_m(*IST_ORIGIN) == pytest.approx(200_000.0, abs=20.0)      # the chord, not the arc
    enu = place(IST_ORIGIN, enu_m=(300.0, -400.0, 5.0))
    assert pymap3d.geodetic2enu(*enu, *IST_ORIGIN) == pytest.approx((300.0, -400.0, 5.0), abs=1e-6)
    assert place(IST_ORIGIN) == IST_ORIGIN
    with pytest.raises(ValueError):
        place(IST_ORIGIN, -1.0)


def single_point_fix(base: BaseStation, epoch) -> np.ndarray:
    """Where the pseudoranges put the antenna: least squares with a clock, each satellite
    taken at its transmission time and turned with the Earth during the signal's flight,
    the satellite clocks and the atmosphere removed as the sky model made them (as a
    receiver does with the broadcast ephemeris and its models)."""
    from viena.services.ntrip.simulator.base import ZENITH_TROPO_M, _sat_clock

    x = np.zeros(4)                                        # from the Earth's centre
    for _ in range(8):
        rows, residuals = [], []
        for o in epoch.of("GPS"):
            c = sky.GPS
            index = int(np.flatnonzero(c.ids == o.sat)[0])
            p = o.signals[1].pseudorange_m
            dt_sat = _sat_clock("GPS", o.sat)[0] + _sat_clock("GPS", o.sat)[1] * (epoch.gps_s % 86400.0 - 43200.0)
            el = math.radians(o.elevation_deg)
            p += rtcm.C_MPS * dt_sat - ZENITH_TROPO_M * 1.001 / math.sqrt(0.002001 + math.sin(el) ** 2)
            p -= base._vertical_iono_m(epoch.gps_s) * base._obliquity(el)
            tau = p / rtcm.C_MPS
            sat = c.ecef_m(epoch.gps_s - x[3] / rtcm.C_MPS - tau)[index]
            turn = sky.OMEGA_E_RADPS * tau
            rot = np.array([[math.cos(turn), math.sin(turn), 0], [-math.sin(turn), math.cos(turn), 0], [0, 0, 1]])
            sat = rot @ sat
            rho = np.linalg.norm(sat - x[:3])
            rows.append([*((x[:3] - sat) / rho), 1.0])
            residuals.append(p - rho - x[3])
        dx, *_ = np.linalg.lstsq(np.array(rows), np.array(residuals), rcond=None)
        x += dx
    return x


def test_a_position_solved_from_the_bases_pseudoranges_is_the_base():
    """Honest geometry: what the base measures puts it where it stands, to the metre its
    multipath and noise leave (a sign error in the Earth's rotation would be 20 m off)."""
    base = BaseStation.at(IST_ORIGIN, 5000.0, 120.0, seed=3)
    epoch = base.observe(T0)
    assert len(epoch.of("GPS")) >= 5
    x = single_point_fix(base, epoch)
    assert np.linalg.norm(x[:3] - base.ecef_m) < 3.0
    assert x[3] / rtcm.C_MPS == pytest.approx(base.clock_bias_s(T0), abs=2e-8)


def test_carrier_phase_is_the_range_plus_a_constant_ambiguity():
    """Over a pass the phase follows the code but for the ambiguity (constant while the lock
    holds), the ionosphere's sign and the noise; the lock time grows with the epochs."""
    base = BaseStation.at(IST_ORIGIN, 1000.0, 0.0, seed=5)
    first, later = base.observe(T0), base.observe(T0 + 60)
    common = {o.sat for o in first.of("GPS")} & {o.sat for o in later.of("GPS")}
    assert common
    for sat in common:
        a = next(o for o in first.of("GPS") if o.sat == sat).signals[1]
        b = next(o for o in later.of("GPS") if o.sat == sat).signals[1]
        assert b.lock_s == pytest.approx(a.lock_s + 60)
        assert abs((b.phase_range_m - b.pseudorange_m) - (a.phase_range_m - a.pseudorange_m)) < 3.0
        assert abs(a.phase_range_m - a.pseudorange_m) < 200.0              # fits DF012's 262 m


def test_a_satellite_that_rises_is_locked_from_its_rise():
    base = BaseStation(*IST_ORIGIN, seed=1)
    seen = {s for s, _, _ in base.visible("GPS", T0)}
    for k in range(1, 3600):
        rising = {s for s, _, _ in base.visible("GPS", T0 + k)} - seen
        if rising:
            break
    sat = rising.pop()
    o = next(o for o in base.observe(T0 + k).of("GPS") if o.sat == sat)
    assert 0.0 <= o.signals[1].lock_s < 1.0
    assert o.elevation_deg == pytest.approx(10.0, abs=0.01)
    late = BaseStation(*IST_ORIGIN, seed=1, since_gps_s=T0 + k + 50)     # a base started after the rise
    assert next(o for o in late.observe(T0 + k + 100).of("GPS") if o.sat == sat).signals[1].lock_s == pytest.approx(50.0)


def test_the_same_seed_gives_the_same_bytes_whatever_came_before():
    a, b = BaseStation.at(IST_ORIGIN, 3000.0, 10.0, seed=7), BaseStation.at(IST_ORIGIN, 3000.0, 10.0, seed=7)
    b.observe(T0 + 500)
    b.observe(T0 - 7200)
    for number in (1004, 1074, 1084):
        assert schedule.build(number, a, a.observe(T0)) == schedule.build(number, b, b.observe(T0))
    other = BaseStation.at(IST_ORIGIN, 3000.0, 10.0, seed=8)
    assert schedule.build(1004, other, other.observe(T0)) != schedule.build(1004, a, a.observe(T0))


# -- the schedule ---------------------------------------------------------------------------------------
def test_what_is_due_when():
    assert schedule.due(schedule.RTK, 1_451_000_001) == [1004]
    assert schedule.due(schedule.RTK, 1_451_000_001, first=True) == [1005, 1033, 1004]
    assert schedule.due(schedule.RTK, 1_451_000_020) == [1005, 1004]
    assert schedule.due(schedule.RTK, 1_451_000_010) == [1005, 1033, 1004]       # a multiple of 30 s too
    assert schedule.due(schedule.MSM, 1_451_000_003) == [1074, 1084]
    assert schedule.format_details(schedule.RTK) == "1004(1),1005(10),1033(30)"
    assert schedule.format_of(schedule.RTK) == "RTCM 3.1" and schedule.format_of(schedule.MSM) == "RTCM 3.2"
    assert (schedule.carrier_of(schedule.RTK), schedule.carrier_of(schedule.L1)) == (2, 1)
    assert schedule.nav_system_of(schedule.MSM) == "GPS+GLO"
    with pytest.raises(ValueError, match="1077"):
        schedule.check({1077: 1})


def test_a_stream_of_a_minute_is_what_the_table_says():
    base = BaseStation.at(IST_ORIGIN, 2000.0, 45.0, station_id=321, seed=2)
    sent = schedule.stream(base, T0, 60)
    numbers = [n for _, n, _ in sent]
    assert numbers.count(1004) == 60
    later = range(T0 + 1, T0 + 60)
    assert numbers.count(1005) == 1 + sum(t % 10 == 0 for t in later)       # at connect, then every 10 s
    assert numbers.count(1033) == 1 + sum(t % 30 == 0 for t in later)       # at connect, then every 30 s
    assert numbers[:3] == [1005, 1033, 1004]
    for t, n, frame in sent:
        parsed = parse(frame)
        assert int(parsed.identity) == n and parsed.DF003 == 321
        if n == 1004:
            assert parsed.DF004 == (t % 604_800) * 1000 and parsed.DF005 == 0
        if n == 1005:
            assert (parsed.DF025, parsed.DF026, parsed.DF027) == pytest.approx(tuple(base.ecef_m), abs=1e-4)


def test_msm_epochs_are_flagged_and_glonass_time_is_moscow_time():
    base = BaseStation.at(IST_ORIGIN, 2000.0, 45.0, seed=2)
    frames = schedule.Frames(base).at(schedule.MSM, T0)
    gps, glo = (parse(f) for n, f in frames if n in (1074, 1084))
    assert (gps.DF393, glo.DF393) == (1, 0)
    assert parse(dict(frames)[1006]).DF023 == 1                     # the station serves GLONASS
    assert parse(schedule.Frames(base).at(schedule.RTK, T0)[0][1]).DF023 == 0
    assert gps.DF004 == (T0 % 604_800) * 1000
    utc = datetime(1980, 1, 6, tzinfo=UTC) + timedelta(seconds=T0 - leap_seconds_at_gps(T0 * 10**9))
    moscow = utc + timedelta(hours=3)
    assert glo.DF034 == ((moscow.hour * 60 + moscow.minute) * 60 + moscow.second) * 1000
    assert glo.DF416 == moscow.isoweekday() % 7
    assert GPS_EPOCH_UNIX_S == datetime(1980, 1, 6, tzinfo=UTC).timestamp()
