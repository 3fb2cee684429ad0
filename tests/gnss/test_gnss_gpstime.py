"""GPS week + milliseconds <-> UTC, across leap seconds."""
import calendar

from hypothesis import given, settings
from hypothesis import strategies as st

from viena.services.gnss.driver.gpstime import (
    gps_to_utc_ns,
    leap_seconds_at_utc,
    utc_to_gps,
    utc_to_gps_ns,
)

S = 1_000_000_000


def utc(*ymdhms) -> int:
    return calendar.timegm(ymdhms) * S


def test_gps_epoch_is_week_zero():
    assert utc_to_gps(utc(1980, 1, 6, 0, 0, 0)) == (0, 0)
    assert gps_to_utc_ns(0, 0) == utc(1980, 1, 6, 0, 0, 0)


def test_the_drives_day_had_17_leap_seconds():
    # GPS week 1877 began on Sunday 2015-12-27; GPS ran 17 s ahead of UTC until 2017
    assert gps_to_utc_ns(1877, 0) == utc(2015, 12, 27, 0, 0, 0) - 17 * S
    assert leap_seconds_at_utc(utc(2016, 6, 1, 10, 20, 50)) == 17
    assert leap_seconds_at_utc(utc(2017, 1, 1, 0, 0, 0)) == 18


def test_the_leap_second_of_2016_12_31():
    before = utc(2016, 12, 31, 23, 59, 59)
    after = utc(2017, 1, 1, 0, 0, 0)
    # one UTC second apart, two GPS seconds apart: the inserted 23:59:60
    assert utc_to_gps_ns(after) - utc_to_gps_ns(before) == 2 * S
    for t in (before, after, after + 123_000_000):
        week, ms = utc_to_gps(t)
        assert gps_to_utc_ns(week, ms) == t


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.integers(utc(1980, 1, 6, 0, 0, 0), utc(2100, 1, 1, 0, 0, 0)))
def test_utc_to_gps_and_back(t_ns):
    t_ms = t_ns // 1_000_000 * 1_000_000
    week, ms = utc_to_gps(t_ms)
    assert 0 <= ms < 604_800_000
    assert gps_to_utc_ns(week, ms) == t_ms
