"""The black box's cheap paths: samples taken from zenoh's ring a batch at a time keep
their arrival times (the router's stamps), and a sample's own `t` read at once when it
comes first in the map."""
from __future__ import annotations

import msgpack
import pytest

from viena.common.recorder import RingSubscribers
from viena.common.recording import sample_time

WALL = 1_790_000_000_000_000_000        # the wall clock at the batch, ns
NOW = 5_000_000_000                     # the receive clock at the batch, ns


class Stamp:
    def __init__(self, ns: int):
        self.ns = ns

    def get_time_as_ntp64(self):
        return self

    def as_nanos(self) -> int:
        return self.ns


class Sample:
    def __init__(self, wall_ns: int | None, key: str = "viena/elettra/imu/razor0/sample"):
        self.timestamp = None if wall_ns is None else Stamp(wall_ns)
        self.key_expr, self.encoding = key, "application/msgpack;viena.imu.sample/1"
        self.payload = self

    def to_bytes(self) -> bytes:
        return b"\x80"


class Ring:
    def __init__(self, samples: list[Sample]):
        self.samples = samples

    def try_recv(self) -> Sample | None:
        return self.samples.pop(0) if self.samples else None


class Clocks:
    """The receive clock: the last batch at NOW - 50 ms, this one at NOW."""

    def __init__(self):
        self.times = [NOW - 50_000_000, NOW]

    def __call__(self) -> int:
        return self.times.pop(0)


@pytest.fixture
def rings(monkeypatch):
    monkeypatch.setattr("viena.common.recorder.clock.time_ns", lambda: WALL)
    return RingSubscribers(Clocks())  # type: ignore[arg-type]


def test_a_batch_keeps_each_samples_arrival_by_its_router_stamp(rings):
    taken = rings.take([Ring([Sample(WALL - 40_000_000), Sample(WALL - 30_000_000), Sample(WALL - 1_000)])])
    assert [t for t, *_ in taken] == [NOW - 40_000_000, NOW - 30_000_000, NOW - 1_000]
    assert taken[0][1:] == ("viena/elettra/imu/razor0/sample", "application/msgpack;viena.imu.sample/1", b"\x80")


def test_log_times_stay_within_the_batch_and_only_grow(rings):
    stamps = [WALL - 10**9,            # older than the last batch (another clock): the last batch's time
              WALL - 20_000_000,
              WALL - 25_000_000,       # stamped before the one taken before it: not earlier than that
              WALL + 10**9,            # ahead of this clock: now
              None]                    # no stamp: now
    taken = rings.take([Ring([Sample(s) for s in stamps])])
    assert [t for t, *_ in taken] == [NOW - 50_000_000, NOW - 20_000_000, NOW - 20_000_000, NOW, NOW]


@pytest.mark.parametrize("value", [
    {"t": 1_790_000_000_000_000_000, "x": 1.5},      # the samples' packing: t first, uint64
    {"t": 2**63 - 1},
    {"t": 5},                                        # a small int: packed short, read by skipping
    {"seq": 1, "t": 1_790_000_000_000_000_000},      # t not first (the GNSS fixes)
    {"t": -5}, {"t": 1.5}, {"t": "x"}, {}, {"x": 1},
])
def test_sample_time_at_once_or_by_skipping_reads_the_same(value):
    t = value.get("t")
    expected = t if type(t) is int and 0 <= t < 2**64 else None
    assert sample_time(msgpack.packb(value)) == expected


def test_sample_time_of_what_is_not_a_sample_map():
    assert sample_time(b"") is None
    assert sample_time(msgpack.packb([1, 2])) is None
    assert sample_time(b"\x81\xa1t\xcf\x00") is None             # cut short
    assert sample_time(msgpack.packb({"t": -(2**40)})) is None     # an int64 below 0
