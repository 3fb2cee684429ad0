"""The NMEA path's differential part: GGA quality 2/4/5/9, the age of the differential data
(field 13) and the base station id (field 14) into the fix (OEM4 vol. 2 §3.4.17 GPGGA)."""
from __future__ import annotations

import functools
import operator

import pytest

from viena.common.samples.fix import FIX, monitor_view, read_fix
from viena.services.gnss.driver.nmea import NmeaDecoder
from viena.services.gnss.fixes import fix_from_nmea


def sentence(body: str) -> bytes:
    checksum = functools.reduce(operator.xor, body.encode(), 0)
    return f"${body}*{checksum:02X}\r\n".encode()


def gga(time: str, quality: int, age: str = "", station: str = "") -> bytes:
    return sentence(f"GPGGA,{time},5106.9847,N,11402.2986,W,{quality},10,1.0,1062.22,M,-16.27,M,{age},{station}")


def one_fix(quality: int, age: str = "", station: str = ""):
    decoder = NmeaDecoder()
    fixes = decoder.feed(gga("202134.00", quality, age, station) + gga("202135.00", quality), 1_700_000_000_000_000_000)
    assert len(fixes) == 2
    return fixes[0]


@pytest.mark.parametrize("quality, age, station, pos_type, kind", [
    (4, "1.4", "0119", "NARROW_INT", "fixed"),
    (5, "2", "2050", "NARROW_FLOAT", "float"),
    (2, "7.0", "0001", "PSRDIFF", "dgps"),
    (9, "", "", "WAAS", "sbas"),
])
def test_differential_gga_gives_its_age_and_base(quality, age, station, pos_type, kind):
    nmea = one_fix(quality, age, station)
    assert nmea.diff_age_s == (float(age) if age else None) and nmea.station_id == (station or None)
    sample = fix_from_nmea(nmea, "gps0", 1)
    FIX.encode(sample)
    fix = read_fix(sample)
    assert (fix.pos_type, fix.kind, fix.diff_age_s, fix.base_id) == (
        pos_type, kind, float(age) if age else None, station or None)
    view = monitor_view(sample)
    assert view["solution"] == f"{pos_type} ({kind})"
    assert view["corrections"] == ("-" if not age else f"{float(age):.1f} s, base {station}")


def test_a_single_point_gga_has_no_age_and_no_base():
    nmea = one_fix(1)
    assert (nmea.diff_age_s, nmea.station_id) == (None, None)
    sample = fix_from_nmea(nmea, "gps0", 1)
    assert (sample["diff_age_s"], sample["base_id"], sample["pos_type"]) == (None, None, "SINGLE")
    assert monitor_view(sample)["corrections"] == "-"


def test_a_gga_whose_age_is_not_a_number_is_a_parse_error():
    decoder = NmeaDecoder()
    fixes = decoder.feed(gga("202134.00", 4, "x1", "0119") + gga("202135.00", 4) + gga("202136.00", 4), 0)
    assert decoder.stats.parse_errors == 1 and len(fixes) == 2     # the two good epochs
