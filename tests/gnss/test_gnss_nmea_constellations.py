"""Multi-constellation NMEA receivers: one fix per epoch from all talkers, satellites counted
across systems, and dates checked against the GPS week rollover.

The sentences are written here in the shapes real receivers send (u-blox NEO-M8N with
NMEA 4.0 GN talkers, ZED-F9P with NMEA 4.10 system and signal ids, a receiver that sends a
GPGGA and a GLGGA per epoch), with their checksums computed, not copied."""
from __future__ import annotations

import calendar
import datetime as dt

import pytest

from viena.services.gnss.driver.nmea import NmeaDecoder
from viena.services.gnss.fixes import fix_from_nmea

HOST_NS = calendar.timegm(dt.datetime(2026, 11, 23, 12, 0, 5).timetuple()) * 1_000_000_000


def sentence(body: str) -> bytes:
    checksum = 0
    for ch in body:
        checksum ^= ord(ch)
    return f"${body}*{checksum:02X}\r\n".encode()


def decode(*bodies: str, host_ns: int = HOST_NS, decoder: NmeaDecoder | None = None):
    decoder = decoder or NmeaDecoder()
    fixes = decoder.feed(b"".join(sentence(b) for b in bodies), host_ns)
    return fixes, decoder


def epoch_m8n(t: str) -> list[str]:
    """u-blox NEO-M8N, GPS + GLONASS: GN solution, one GNGSA per system, GSV per talker."""
    return [f"GNRMC,{t},A,3844.2140,N,00908.3700,W,0.05,,231126,,,A",
            "GNVTG,,T,,M,0.05,N,0.09,K,A",
            f"GNGGA,{t},3844.2140,N,00908.3700,W,1,12,0.9,100.0,M,50.0,M,,",
            "GNGSA,A,3,02,05,12,13,15,18,25,29,,,,,1.6,0.9,1.3",
            "GNGSA,A,3,65,71,72,81,,,,,,,,,1.6,0.9,1.3",
            "GPGSV,4,1,13,02,40,080,40,05,60,150,42,12,30,300,38,13,20,045,35",
            "GPGSV,4,2,13,15,55,220,41,18,10,180,30,20,05,010,,21,03,330,",
            "GPGSV,4,3,13,25,70,100,44,26,02,270,,29,35,120,39,31,08,060,",
            "GPGSV,4,4,13,33,30,200,37",
            "GLGSV,3,1,10,65,45,050,36,66,10,110,,71,30,210,33,72,60,300,40",
            "GLGSV,3,2,10,73,05,020,,74,02,350,,80,12,140,,81,50,250,38",
            "GLGSV,3,3,10,82,20,080,,88,07,190,"]


def test_a_combined_solution_counts_every_system():
    fixes, decoder = decode(*epoch_m8n("120005.00"), *epoch_m8n("120005.10")[:1])
    assert len(fixes) == 1
    fix = fixes[0]
    assert fix.talker == "GN" and fix.talkers == ("GL", "GN", "GP")
    assert fix.sats_used == 12                  # 8 GPS + 4 GLONASS, from both GNGSA
    assert fix.sats_in_view == 23               # 13 GPS + 10 GLONASS, from every GSV
    assert fix.lat_deg == pytest.approx(38 + 44.214 / 60)
    assert decoder.stats.checksum_errors == decoder.stats.parse_errors == 0


def test_the_second_epoch_is_handed_on_as_soon_as_it_is_whole():
    """Every talker's sentences count: the epoch is complete only once each GSV has ended."""
    first, decoder = decode(*epoch_m8n("120005.00"), *epoch_m8n("120005.10"))
    assert len(first) == 2 and first[1].utc_ns - first[0].utc_ns == 100_000_000
    assert first[1].sats_in_view == 23


def test_a_glonass_only_gga_never_replaces_the_gps_solution():
    """Receivers that send GPGGA and GLGGA in one epoch: the GLONASS sentence came last."""
    t = "120005.00"
    fixes, _ = decode(f"GPRMC,{t},A,3844.2140,N,00908.3700,W,0.0,,231126,,,A",
                      f"GPGGA,{t},3844.2140,N,00908.3700,W,1,08,1.0,100.0,M,50.0,M,,",
                      f"GLGGA,{t},3844.9999,N,00908.9999,W,1,02,9.9,120.0,M,50.0,M,,",
                      "GPGSA,A,3,02,05,12,13,15,18,25,29,,,,,1.8,1.0,1.5",
                      "GLGSA,A,2,65,71,,,,,,,,,,,9.9,9.9,9.9",
                      "GPRMC,120005.10,A,3844.2140,N,00908.3700,W,0.0,,231126,,,A")
    fix = fixes[0]
    assert fix.talker == "GP" and fix.lat_deg == pytest.approx(38 + 44.214 / 60)
    assert fix.sats_used == 10 and fix.fix_mode == 3 and fix.hdop == pytest.approx(1.0)


def test_nmea_4_10_system_and_signal_ids():
    """ZED-F9P: GNGSA per system with a system id, GSV with a signal id, four systems."""
    t = "120005.00"
    fixes, decoder = decode(
        f"GNRMC,{t},A,3844.2140,N,00908.3700,W,0.10,45.0,231126,,,D,V",
        f"GNGGA,{t},3844.2140,N,00908.3700,W,2,20,0.6,100.0,M,50.0,M,,",
        "GNGSA,A,3,02,05,12,13,15,18,,,,,,,1.1,0.6,0.9,1",
        "GNGSA,A,3,65,71,72,,,,,,,,,,1.1,0.6,0.9,2",
        "GNGSA,A,3,02,05,07,11,,,,,,,,,1.1,0.6,0.9,3",          # Galileo PRNs 2 and 5 too
        "GNGSA,A,3,19,20,22,,,,,,,,,,1.1,0.6,0.9,4",
        "GPGSV,2,1,07,02,40,080,40,05,60,150,42,12,30,300,38,13,20,045,35,1",
        "GPGSV,2,2,07,15,55,220,41,18,10,180,30,20,05,010,,1",
        "GLGSV,1,1,04,65,45,050,36,71,30,210,33,72,60,300,40,80,12,140,,1",
        "GAGSV,2,1,05,02,40,080,40,05,60,150,42,07,30,300,38,11,20,045,35,7",
        "GAGSV,2,2,05,30,10,100,,7",
        "GBGSV,1,1,04,19,40,080,40,20,60,150,42,22,30,300,38,35,20,045,35,1",
        "GNRMC,120005.10,A,3844.2140,N,00908.3700,W,0.10,45.0,231126,,,D,V")
    fix = fixes[0]
    assert fix.sats_used == 16                 # Galileo 2 and 5 are not GPS 2 and 5
    assert fix.sats_in_view == 20
    assert fix.quality == 2 and fix.talkers == ("GA", "GB", "GL", "GN", "GP")
    assert decoder.stats.parse_errors == 0


def test_empty_fields_and_checksum_errors_are_counted_never_published():
    t = "120005.00"
    damaged = sentence(f"GNGGA,{t},3844.2140,N,00908.3700,W,1,12,0.9,100.0,M,50.0,M,,")
    damaged = damaged.replace(b"3844.2140", b"3844.2141")           # one digit flipped on the line
    decoder = NmeaDecoder()
    fixes = decoder.feed(sentence(f"GNRMC,{t},V,,,,,,,231126,,,N") + damaged
                         + sentence(f"GNGGA,{t},,,,,0,00,99.99,,,,,,")
                         + sentence("GNGSA,A,1,,,,,,,,,,,,,99.99,99.99,99.99")
                         + sentence("GPGSV,1,1,00") + sentence("GNRMC,120005.10,V,,,,,,,231126,,,N"),
                         HOST_NS)
    assert decoder.stats.checksum_errors == 1
    assert len(fixes) == 1 and not fixes[0].has_position and fixes[0].sats_used == 0
    assert fix_from_nmea(fixes[0], "gps0", 0) is None


def test_a_date_1024_weeks_back_is_moved_on_when_the_host_clock_agrees():
    t = "120005.00"
    # 2026-11-23 less 1024 weeks is 2007-04-09
    fixes, decoder = decode(f"GPRMC,{t},A,3844.2140,N,00908.3700,W,0.0,,090407,,,A",
                            f"GPGGA,{t},3844.2140,N,00908.3700,W,1,08,1.0,100.0,M,50.0,M,,",
                            "GPRMC,120005.10,A,3844.2140,N,00908.3700,W,0.0,,090407,,,A")
    assert decoder.stats.rollover_corrected == 1 and fixes[0].date_problem is None
    assert abs(fixes[0].utc_ns - HOST_NS) < 1_000_000_000
    assert fix_from_nmea(fixes[0], "gps0", 0)["valid"]


def test_a_1999_date_the_host_cannot_settle_is_not_a_valid_fix():
    t = "120005.00"
    fixes, decoder = decode(f"GPRMC,{t},A,3844.2140,N,00908.3700,W,0.0,,150899,,,A",
                            f"GPGGA,{t},3844.2140,N,00908.3700,W,1,08,1.0,100.0,M,50.0,M,,",
                            "GPRMC,120005.10,A,3844.2140,N,00908.3700,W,0.0,,150899,,,A")
    assert decoder.stats.rollover_refused == 1
    assert "1999-08-15" in fixes[0].date_problem and "rollover" in fixes[0].date_problem
    sample = fix_from_nmea(fixes[0], "gps0", 0)
    assert sample is not None and not sample["valid"]
