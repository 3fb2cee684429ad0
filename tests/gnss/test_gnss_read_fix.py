"""The typed fix: what a consumer (the estimator) reads of a viena.gnss.fix/1 sample, from
viena's own receivers or from any source that publishes the fields the README lists."""
from __future__ import annotations

import math

import pytest

from viena.common.samples.fix import FIX, Fix, read_fix
from viena.common.schema import FieldError
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
from viena.services.gnss.fixes import fix_from_bestpos, fix_from_bestxyz, fix_from_nmea

WEEK, MS = 1899, 296_450_300
T = gps_to_utc_ns(WEEK, MS)
OK, NONE = SolutionStatus.SOL_COMPUTED, SolutionStatus.INSUFFICIENT_OBS
ECEF = (4918535.4, -791215.6, 3969669.3)


def log(data):
    return LogMessage(Header(data.MESSAGE_ID, week=WEEK, milliseconds=MS, time_status=180), data, T + 30_000_000)


def xyz(vel_status=OK):
    return BestXyz(OK, PositionType.SINGLE, ECEF, (1.5, 1.2, 2.0), vel_status, PositionType.DOPPLER_VELOCITY,
                   (0.5, -0.2, 0.1), (0.03,) * 3, "", 0.15, 0.0, 0.0, 9, 8)


def own_fixes() -> list[dict]:
    """One fix of each kind viena's GNSS service publishes, as a subscriber decodes them."""
    pos = BestPos(OK, PositionType.SINGLE, 38.7369, -9.1395, 50.0, 50.0, lat_sigma_m=1.0, lon_sigma_m=1.0,
                  height_sigma_m=2.0, sats_tracked=9)
    vel = BestVel(OK, PositionType.DOPPLER_VELOCITY, latency_s=0.15, diff_age_s=0.0, hor_speed_mps=5.0,
                  track_deg=90.0, vert_speed_mps=0.1)
    nmea = NmeaFix(utc_ns=T, t_host_ns=T + 50_000_000, quality=1, lat_deg=38.7369, lon_deg=-9.1395,
                   height_msl_m=50.0, geoid_sep_m=50.0, sats_used=8, hdop=0.9, speed_mps=5.0, course_deg=90.0)
    fixes = [fix_from_bestxyz(log(xyz()), "gnss0", 1), fix_from_bestxyz(log(xyz(NONE)), "gnss0", 2),
             fix_from_bestpos(log(pos), log(vel), "gnss1", 3), fix_from_bestpos(log(pos), None, "gnss1", 4),
             fix_from_nmea(nmea, "gnss2", 5)]
    return [FIX.decode(FIX.encode(f)) for f in fixes]


@pytest.mark.parametrize("sample", own_fixes(), ids=["bestxyz", "bestxyz-no-vel", "bestpos+vel", "bestpos", "nmea"])
def test_every_fix_viena_publishes_reads_as_it_is(sample):
    fix = read_fix(sample)
    assert isinstance(fix, Fix)
    for name in Fix._fields:
        value = getattr(fix, name)
        assert (list(value) if isinstance(value, tuple) else value) == sample.get(name), name
    assert all(type(v) is float for v in fix.ecef_m + fix.ecef_sigma_m)
    assert fix.usable is (sample["valid"] and sample["pos_status"] == "SOL_COMPUTED")
    assert fix.has_velocity is (sample["vel_ecef_mps"] is not None and sample["vel_status"] == "SOL_COMPUTED")


def test_a_fix_from_another_source_needs_only_the_fields_the_readme_lists():
    sample = {"t": T, "valid": True, "ecef_m": list(ECEF), "ecef_sigma_m": [2, 2, 3]}
    fix = read_fix(sample)
    assert (fix.unit, fix.pos_status, fix.vel_status) == ("gnss", "SOL_COMPUTED", "SOL_COMPUTED")
    assert fix.vel_latency_s == 0.0
    assert fix.usable and not fix.has_velocity and fix.vel_sigma_mps is None
    assert fix.ecef_sigma_m == (2.0, 2.0, 3.0) and sample["ecef_sigma_m"] == [2, 2, 3]
    with_vel = read_fix({**sample, "vel_ecef_mps": (0.0, 1.0, 0.0), "vel_latency_s": 0.1})
    assert with_vel.has_velocity and with_vel.vel_ecef_mps == (0.0, 1.0, 0.0)
    assert not with_vel.without_velocity().has_velocity


@pytest.mark.parametrize("change, field, not_finite", [
    ({"ecef_m": [math.nan, 0.0, 0.0]}, "ecef_m", True),
    ({"vel_ecef_mps": [0.0, -math.inf, 0.0]}, "vel_ecef_mps", True),
    ({"ecef_sigma_m": [1.0, 1.0]}, "ecef_sigma_m", False),
    ({"valid": 1}, "valid", False),
    ({"pos_status": None}, "pos_status", False),
    ({"t": 5}, "t", False),
])
def test_a_wrong_field_is_named(change, field, not_finite):
    sample = {"t": T, "unit": "x", "valid": True, "ecef_m": list(ECEF), "ecef_sigma_m": [2.0, 2.0, 3.0]}
    with pytest.raises(FieldError, match=field) as caught:
        read_fix({**sample, **change})
    assert (caught.value.field, caught.value.not_finite) == (field, not_finite)
