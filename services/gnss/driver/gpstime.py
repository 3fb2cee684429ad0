"""GPS time (week + milliseconds) to UTC and back.

GPS time started at 1980-01-06 00:00:00 UTC and does not stop for leap seconds, so
UTC = GPS - (GPS-UTC offset at that instant). The receiver stamps every log with GPS
time (docs/sensors.md#gps-time-to-utc); the samples carry UTC (docs/dataflow.md#time), so the conversion
lives here.
All instants are integer nanoseconds on the POSIX (leap-second-free) UTC scale.
"""
from __future__ import annotations

import bisect
import calendar

SECONDS_PER_WEEK = 604_800
NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000
#: 1980-01-06T00:00:00Z in POSIX seconds.
GPS_EPOCH_UNIX_S = calendar.timegm((1980, 1, 6, 0, 0, 0))

#: (UTC date from which the offset applies, GPS-UTC seconds). IERS Bulletin C; the last
#: leap second was 2016-12-31 and none has been announced since.
LEAP_SECONDS = (
    ((1981, 7, 1), 1), ((1982, 7, 1), 2), ((1983, 7, 1), 3), ((1985, 7, 1), 4),
    ((1988, 1, 1), 5), ((1990, 1, 1), 6), ((1991, 1, 1), 7), ((1992, 7, 1), 8),
    ((1993, 7, 1), 9), ((1994, 7, 1), 10), ((1996, 1, 1), 11), ((1997, 7, 1), 12),
    ((1999, 1, 1), 13), ((2006, 1, 1), 14), ((2009, 1, 1), 15), ((2012, 7, 1), 16),
    ((2015, 7, 1), 17), ((2017, 1, 1), 18),
)

_UTC_STEPS_NS = [calendar.timegm((*d, 0, 0, 0)) * NS_PER_S for d, _ in LEAP_SECONDS]
_OFFSETS_S = [0] + [off for _, off in LEAP_SECONDS]
# The same steps on the GPS scale (ns since the GPS epoch): a step at UTC instant T
# happens at GPS time T - epoch + new offset.
_GPS_STEPS_NS = [u - GPS_EPOCH_UNIX_S * NS_PER_S + off * NS_PER_S
                 for u, (_, off) in zip(_UTC_STEPS_NS, LEAP_SECONDS)]


def leap_seconds_at_utc(utc_ns: int) -> int:
    """GPS-UTC in whole seconds at a UTC instant."""
    return _OFFSETS_S[bisect.bisect_right(_UTC_STEPS_NS, utc_ns)]


def leap_seconds_at_gps(gps_ns: int) -> int:
    """GPS-UTC in whole seconds at a GPS instant (ns since the GPS epoch)."""
    return _OFFSETS_S[bisect.bisect_right(_GPS_STEPS_NS, gps_ns)]


def gps_to_utc_ns(week: int, milliseconds: int) -> int:
    """UTC instant (POSIX ns) of a GPS week and millisecond of week."""
    gps_ns = (week * SECONDS_PER_WEEK * 1000 + milliseconds) * NS_PER_MS
    return gps_ns + (GPS_EPOCH_UNIX_S - leap_seconds_at_gps(gps_ns)) * NS_PER_S


def utc_to_gps_ns(utc_ns: int) -> int:
    """Nanoseconds since the GPS epoch of a UTC instant."""
    return utc_ns - GPS_EPOCH_UNIX_S * NS_PER_S + leap_seconds_at_utc(utc_ns) * NS_PER_S


def utc_to_gps(utc_ns: int) -> tuple[int, int]:
    """(GPS week, millisecond of week) of a UTC instant, milliseconds rounded down."""
    gps_ms = utc_to_gps_ns(utc_ns) // NS_PER_MS
    week, ms = divmod(gps_ms, SECONDS_PER_WEEK * 1000)
    return int(week), int(ms)
