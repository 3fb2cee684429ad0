"""The black box's cheap paths: samples taken from zenoh's ring a batch at a time keep
their arrival times (the router's stamps), and a sample's own `t` read at once when it
comes first in the map."""
from __future__ import annotations

import logging

import msgpack
import pytest
import zenoh

from viena.common import recorder as recorder_module
from viena.common.recorder import Recorder, RingSubscribers
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
    def __init__(self, samples: list[Sample], closed: bool = False):
        self.samples, self.closed = samples, closed

    def try_recv(self) -> Sample | None:
        if self.samples:
            return self.samples.pop(0)
        if self.closed:
            raise zenoh.ZError("Undeclared subscriber")
        return None


def keys(taken: list) -> list[str]:
    return [key for _, key, *_ in taken]


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
    taken, counts = rings.take([Ring([Sample(WALL - 40_000_000), Sample(WALL - 30_000_000), Sample(WALL - 1_000)])])
    assert [t for t, *_ in taken] == [NOW - 40_000_000, NOW - 30_000_000, NOW - 1_000]
    assert taken[0][1:] == ("viena/elettra/imu/razor0/sample", "application/msgpack;viena.imu.sample/1", b"\x80")
    assert counts == [3]


def test_log_times_stay_within_the_batch_and_only_grow(rings):
    stamps = [WALL - 10**9,            # older than the last batch (another clock): the last batch's time
              WALL - 20_000_000,
              WALL - 25_000_000,       # stamped before the one taken before it: not earlier than that
              WALL + 10**9,            # ahead of this clock: now
              None]                    # no stamp: the one before it
    taken, _ = rings.take([Ring([Sample(s) for s in stamps])])
    assert [t for t, *_ in taken] == [NOW - 50_000_000, NOW - 20_000_000, NOW - 20_000_000, NOW, NOW]


def test_a_sample_without_a_stamp_does_not_push_the_later_ones_to_the_batch_time(rings, caplog):
    stamps = [WALL - 40_000_000, None, WALL - 30_000_000, WALL - 20_000_000]
    taken, _ = rings.take([Ring([Sample(s) for s in stamps])])
    assert [t for t, *_ in taken] == [NOW - 40_000_000, NOW - 40_000_000, NOW - 30_000_000, NOW - 20_000_000]
    assert "without a zenoh timestamp" not in caplog.text


def test_a_batch_with_no_stamp_at_all_is_said_once(monkeypatch, caplog):
    monkeypatch.setattr("viena.common.recorder.clock.time_ns", lambda: WALL)
    times = iter(range(0, 10**10, 50_000_000))
    rings = RingSubscribers(lambda: next(times))  # type: ignore[arg-type]
    with caplog.at_level(logging.WARNING, "viena.recorder"):
        for _ in range(3):
            rings.take([Ring([Sample(None), Sample(None)])])
    assert caplog.text.count("without a zenoh timestamp") == 1


def test_several_rings_are_merged_by_arrival_not_clamped_by_each_other(rings):
    imu = "viena/elettra/imu/razor0/sample"
    gnss = "viena/elettra/gnss/gnss0/fix"
    taken, counts = rings.take([
        Ring([Sample(WALL - 10_000_000, imu), Sample(WALL - 5_000_000, imu)]),
        Ring([Sample(WALL - 40_000_000, gnss), Sample(WALL - 30_000_000, gnss)]),
    ])
    assert [t for t, *_ in taken] == [NOW - 40_000_000, NOW - 30_000_000, NOW - 10_000_000, NOW - 5_000_000]
    assert keys(taken) == [gnss, gnss, imu, imu]
    assert counts == [2, 2]


def test_a_ring_without_stamps_takes_the_last_batchs_end(rings):
    imu, path = "viena/elettra/imu/razor0/sample", "viena/elettra/pilot/path"
    taken, _ = rings.take([
        Ring([Sample(WALL - 30_000_000, imu), Sample(WALL - 10_000_000, imu)]),
        Ring([Sample(None, path)]),                  # the last batch's end: before everything
    ])
    assert keys(taken) == [path, imu, imu]
    assert [t for t, *_ in taken] == [NOW - 50_000_000, NOW - 30_000_000, NOW - 10_000_000]


def test_a_closed_subscriber_gives_what_it_had_and_is_said_once(rings, caplog):
    with caplog.at_level(logging.WARNING, "viena.recorder"):
        taken, counts = rings.take([Ring([Sample(WALL - 1_000)], closed=True), Ring([Sample(WALL - 2_000)])])
    assert counts == [1, 1] and len(taken) == 2
    assert caplog.text.count("cannot be read") == 1


class Kept:
    samples = 0

    def __init__(self):
        self.written = []

    def write(self, key, encoding, log_time, data):
        self.written.append(key)


def test_the_largest_batch_is_the_backlog_and_a_full_ring_may_have_dropped(monkeypatch):
    monkeypatch.setattr(recorder_module, "RING_SAMPLES", 3)
    rec = Recorder(None, [], Kept(), batched=True)  # type: ignore[arg-type]
    rec._subscribers = [Ring([Sample(WALL - 1_000)] * 3), Ring([Sample(WALL - 1_000)] * 2)]
    rec._write(rec._taken())
    rec._subscribers = [Ring([Sample(WALL - 1_000)]), Ring([])]
    rec._write(rec._taken())
    assert rec.backlog() == 5 and rec.backlog() == 0          # since the last asked
    assert rec.possibly_dropped == 1


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
