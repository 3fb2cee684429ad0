"""viena.gnss.fix/1: how logs become samples, and what the schema refuses."""
from __future__ import annotations

import math

import pytest

from viena.common.errors import SampleError
from viena.common.samples.fix import FIX
from viena.services.gnss.driver.gpstime import gps_to_utc_ns
from viena.services.gnss.driver.nmea import NmeaFix
from viena.services.gnss.driver.novatel import (
    BestPos,
    BestVel,
    BestXyz,
    Header,
    LogMessage,
    PositionType,
    SolutionStatus,
)
from viena.services.gnss.fixes import NovatelFixBuilder, fix_from_bestxyz, fix_from_nmea

WEEK, MS = 1899, 296_450_300
T_HOST = gps_to_utc_ns(WEEK, MS) + 30_000_000
OK, NONE = SolutionStatus.SOL_COMPUTED, SolutionStatus.INSUFFICIENT_OBS


def log(data, ms=MS, time_status=180, week=WEEK):
    header = Header(data.MESSAGE_ID, week=week, milliseconds=ms, time_status=time_status)
    return LogMessage(header, data, T_HOST)


def xyz(position=(4918535.4, -791215.6, 3969669.3), status=OK, kind=PositionType.SINGLE):
    return BestXyz(status, kind, position, (1.5, 1.2, 2.0), status, PositionType.DOPPLER_VELOCITY,
                   (0.5, -0.2, 0.1), (0.03,) * 3, "", 0.15, 0.0, 0.0, 9, 8)


def test_bestxyz_fix_carries_both_clocks():
    fix = fix_from_bestxyz(log(xyz()), "gnss0", 7)
    FIX.decode(FIX.encode(fix))
    assert fix["t"] == gps_to_utc_ns(WEEK, MS) and fix["t_host"] == T_HOST
    assert fix["latency_s"] == pytest.approx(0.03)
    assert (fix["gps_week"], fix["gps_ms"], fix["time_status"]) == (WEEK, MS, "FINESTEERING")
    assert fix["valid"] and fix["ecef_m"] == [4918535.4, -791215.6, 3969669.3]
    assert fix["lat_deg"] == pytest.approx(38.7369, abs=1e-3)
    assert (fix["sats_tracked"], fix["sats_used"], fix["vel_latency_s"]) == (9, 8, pytest.approx(0.15))


def test_the_no_fix_position_is_kept_and_marked_invalid():
    fix = fix_from_bestxyz(log(xyz((100.0, 0.0, 0.0), NONE, PositionType.NONE)), "gnss0", 1)
    FIX.encode(fix)
    assert not fix["valid"] and fix["ecef_m"] == [100.0, 0.0, 0.0]
    assert (fix["pos_status"], fix["pos_type"]) == ("INSUFFICIENT_OBS", "NONE")
    # even SOL_COMPUTED at the no-fix position is not a fix
    assert not fix_from_bestxyz(log(xyz((100.0, 0.0, 0.0))), "gnss0", 1)["valid"]


def test_a_receiver_without_time_is_stamped_with_the_host_clock():
    fix = fix_from_bestxyz(log(xyz(), ms=12_000, week=0, time_status=20), "gnss0", 1)
    assert fix["t"] == T_HOST and fix["latency_s"] == 0.0 and fix["time_status"] == "UNKNOWN"


def test_the_schema_refuses_a_bad_sample():
    fix = fix_from_bestxyz(log(xyz()), "gnss0", 1)
    for field, value in (("ecef_m", [math.nan, 0.0, 0.0]), ("protocol", "sirf"), ("t", 5)):
        with pytest.raises(SampleError, match=field):
            FIX.encode({**fix, field: value})


def bestpos(ms=MS):
    return log(BestPos(OK, PositionType.SINGLE, 38.7369, -9.1395, 45.0, 55.0,
                       lat_sigma_m=1.2, lon_sigma_m=1.5, height_sigma_m=2.0, sats_used=8), ms)


def bestvel(ms=MS):
    return log(BestVel(OK, PositionType.DOPPLER_VELOCITY, 0.15, 0.0, 3.0, 90.0, 0.0), ms)


@pytest.mark.parametrize("order", [("pos", "vel"), ("vel", "pos")])
def test_bestpos_and_bestvel_of_an_epoch_make_one_fix(order):
    builder = NovatelFixBuilder("gnss0")
    logs = {"pos": bestpos(), "vel": bestvel()}
    out = [f for name in order for f in builder.add(logs[name])]
    assert len(out) == 1
    fix = out[0]
    FIX.encode({**fix, "seq": 1})
    assert fix["height_m"] == pytest.approx(100.0)
    east = fix["vel_ecef_mps"]
    assert math.hypot(*east) == pytest.approx(3.0)          # 3 m/s heading east
    assert fix["vel_status"] == "SOL_COMPUTED"


def test_a_bestpos_whose_bestvel_never_comes_goes_out_at_the_next_epoch():
    builder = NovatelFixBuilder("gnss0")
    assert builder.add(bestpos(MS)) == []
    out = builder.add(bestpos(MS + 50))
    assert len(out) == 1 and out[0]["vel_ecef_mps"] is None and out[0]["gps_ms"] == MS


def test_with_bestxyz_logged_bestpos_adds_no_fixes():
    builder = NovatelFixBuilder("gnss0")
    assert len(builder.add(log(xyz()))) == 1
    assert builder.add(bestpos()) == [] and builder.add(bestvel()) == []


def nmea(**kw):
    base = dict(utc_ns=T_HOST - 30_000_000, t_host_ns=T_HOST, quality=1, lat_deg=38.7369,
                lon_deg=-9.1395, height_msl_m=45.0, geoid_sep_m=55.0, sats_used=8,
                sats_in_view=11, hdop=1.0, vdop=1.5, fix_mode=3, rmc_valid=True,
                speed_mps=2.0, course_deg=0.0)
    base.update(kw)
    return NmeaFix(**base)


def test_nmea_epoch_to_fix():
    fix = fix_from_nmea(nmea(), "gps0", 3, uere_m=3.0)
    FIX.encode(fix)
    assert fix["valid"] and (fix["pos_status"], fix["pos_type"]) == ("SOL_COMPUTED", "SINGLE")
    assert fix["height_m"] == pytest.approx(100.0) and fix["sats_tracked"] == 11
    assert (fix["gps_week"], fix["gps_ms"]) == (WEEK, MS)
    assert math.hypot(*fix["vel_ecef_mps"]) == pytest.approx(2.0)
    # sigmas: HDOP x UERE shared by east and north, VDOP x UERE up, seen along ECEF axes
    assert math.hypot(*fix["ecef_sigma_m"]) == pytest.approx(math.hypot(3 / 2 ** 0.5, 3 / 2 ** 0.5, 4.5))


@pytest.mark.parametrize("quality, status, kind", [
    (0, "INSUFFICIENT_OBS", "NONE"), (2, "SOL_COMPUTED", "PSRDIFF"),
    (4, "SOL_COMPUTED", "NARROW_INT"), (5, "SOL_COMPUTED", "NARROW_FLOAT"),
    (6, "SOL_COMPUTED", "PROPAGATED"), (8, "INSUFFICIENT_OBS", "NONE"),
    (9, "SOL_COMPUTED", "WAAS"),        # NovAtel's GPGGA (OEM4 vol. 2 §3.4.17)
])
def test_nmea_quality_in_novatel_terms(quality, status, kind):
    fix = fix_from_nmea(nmea(quality=quality), "gps0", 1)
    assert (fix["pos_status"], fix["pos_type"], fix["valid"]) == (status, kind, status == "SOL_COMPUTED")


def test_nmea_without_a_position_makes_no_sample():
    assert fix_from_nmea(nmea(quality=0, lat_deg=None, lon_deg=None, height_msl_m=None), "g", 1) is None
