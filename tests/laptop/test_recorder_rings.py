"""The batched recorder on a real router (zenoh's rings, timestamping on as the car's router
has it): every sample heard before `stop()` is written, those still in the rings too, and a
ring that filled up is reported, not silent."""
from __future__ import annotations

from pathlib import Path

import pytest
from vienatest import open_session, wait_for_subscriber, wait_until

from viena.common import recorder as recorder_module
from viena.common.recorder import Recorder

KEY = "viena/elettra/test/ring"
N = 500


class Kept:
    """A SampleWriter that keeps what it is given."""

    part = Path("kept.part")
    keys = 1
    size = 0

    def __init__(self):
        self.written: list[tuple[str, int, bytes]] = []

    @property
    def samples(self) -> int:
        return len(self.written)

    def write(self, key: str, encoding: str, log_time: int, data: bytes) -> None:
        self.written.append((key, log_time, data))

    def flush(self) -> None:
        pass

    def close(self) -> Path:
        return self.part

    def abandon(self) -> None:
        pass

    def discard(self) -> None:
        pass


@pytest.fixture
def sessions(router):
    recording, car = open_session(router), open_session(router)
    yield recording, car
    car.close()
    recording.close()


def record_then_stop(sessions, n: int) -> tuple[Recorder, Kept]:
    """`n` samples put while the writing thread sleeps (BATCH_S is long): all of them still
    in zenoh's ring when `stop()` comes, as the last 50 ms of a drive are."""
    recording, car = sessions
    kept = Kept()
    rec = Recorder(recording, [KEY], kept, batched=True)
    heard = []
    counter = recording.declare_subscriber(KEY, lambda sample: heard.append(1))  # arrives with the ring's
    rec.start()
    assert wait_for_subscriber(car, KEY)
    publisher = car.declare_publisher(KEY)
    for i in range(n):
        publisher.put(i.to_bytes(4, "big"))
    assert wait_until(lambda: len(heard) == n, 20)
    assert rec.stop() == kept.part
    counter.undeclare()
    return rec, kept


def test_stop_writes_what_is_still_in_the_rings(sessions, monkeypatch):
    monkeypatch.setattr(recorder_module, "BATCH_S", 30.0)     # no take before stop()
    rec, kept = record_then_stop(sessions, N)
    assert [int.from_bytes(d, "big") for _, _, d in kept.written] == list(range(N))
    times = [t for _, t, _ in kept.written]
    assert times == sorted(times)
    assert rec.possibly_dropped == 0 and rec.backlog() == N


def test_a_ring_that_filled_up_is_reported(sessions, monkeypatch):
    monkeypatch.setattr(recorder_module, "BATCH_S", 30.0)
    monkeypatch.setattr(recorder_module, "RING_SAMPLES", 50)
    rec, kept = record_then_stop(sessions, 200)
    assert [int.from_bytes(d, "big") for _, _, d in kept.written] == list(range(150, 200))   # the newest
    assert rec.possibly_dropped == 1
