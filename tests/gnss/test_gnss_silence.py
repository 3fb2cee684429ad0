"""The GNSS service's silence timeout follows the receiver's own pace: each source marks one
epoch per epoch (an NMEA epoch; the NovAtel log its fixes are made from, not every log),
so a slow receiver gets three of its epoch intervals and a 10-20 Hz one keeps 1 s. The
twins' bytes go straight into the drivers on a simulated clock: no sockets, no sleeping."""
from __future__ import annotations

from types import SimpleNamespace

import pytest
from gnss_helpers import TwinHarness, still

from viena.common.health import Health
from viena.common.settings import from_mapping
from viena.common.silence import SilenceWatch
from viena.services.gnss.driver.novatel import Log, MessageId, Trigger
from viena.services.gnss.service import GnssSettings, NmeaSource, NovatelSource
from viena.services.gnss.simulator import NmeaTwin, NovatelTwin

T0_NS = 1_700_000_000_000_000_000
BYTE_NS = 10 / 115200 * 1e9


class Clock:
    def __init__(self):
        self.now_s = 0.0

    def __call__(self) -> int:
        return T0_NS + round(self.now_s * 1e9)


def stub_service(clock: Clock, **settings):
    """What a source uses of its service, without zenoh: fixes are collected."""
    s = from_mapping(GnssSettings, {"port": "loop://", **settings}, "test")
    published = []
    return SimpleNamespace(
        settings=s, unit="gnss0", health=Health("gnss", "gnss0"), published=published,
        silence=SilenceWatch(s.silence_timeout_s, epochs=s.silence_epochs, clock=clock),
        publish_all=lambda build: published.extend(build()))


def stream(twin, receiver, clock: Clock, t_start_s: float, seconds: float) -> None:
    """The twin's bytes into the driver as they would arrive: 64 bytes at a time, each
    piece stamped when its last byte is through at 115200 baud."""
    clock.now_s = t_start_s
    while clock.now_s < t_start_s + seconds:
        clock.now_s = max(clock.now_s + 1e-3, twin.next_due(clock.now_s))
        data = twin.poll(clock.now_s)
        for i in range(0, len(data), 64):
            piece = data[i:i + 64]
            receiver._on_bytes(piece, clock() + round((i + len(piece)) * BYTE_NS))


@pytest.mark.parametrize("rate_hz, timeout_s", [(1 / 1.06, 3.18), (10.0, 1.0)])
def test_an_nmea_receiver_gets_three_of_its_epochs(rate_hz, timeout_s):
    clock = Clock()
    service = stub_service(clock, protocol="nmea")
    source = NmeaSource(service)
    twin = NmeaTwin(still(), seed=2, rate_hz=rate_hz, outage_interval_s=0.0)
    twin.on_connect(0.0)
    stream(twin, source.receiver, clock, 0.0, 12.0)
    assert len(service.published) >= 10
    assert service.silence.timeout_s == pytest.approx(timeout_s, abs=0.01)


def test_a_novatel_receiver_marks_one_epoch_per_bestpos_and_bestvel_pair():
    clock = Clock()
    service = stub_service(clock, logs=["BESTPOS", "BESTVEL"])
    source = NovatelSource(service)
    harness = TwinHarness(NovatelTwin(still(), seed=3, outage_interval_s=0.0), t0=0.0)
    for log in (MessageId.BESTPOS, MessageId.BESTVEL):
        harness.command(Log(message=log, trigger=Trigger.ONTIME, period=1.0))
    stream(harness.twin, source.receiver, clock, harness.now, 10.0)
    assert len(service.published) >= 8                 # one fix per epoch, both logs joined
    assert service.silence.timeout_s == pytest.approx(3.0, abs=0.01)


def test_without_silence_epochs_the_timeout_is_fixed():
    clock = Clock()
    service = stub_service(clock, protocol="nmea", silence_epochs=0.0)
    assert service.silence.epochs == 0.0
    source = NmeaSource(service)
    twin = NmeaTwin(still(), seed=2, rate_hz=0.5, outage_interval_s=0.0)
    twin.on_connect(0.0)
    stream(twin, source.receiver, clock, 0.0, 10.0)
    assert service.published and service.silence.timeout_s == 1.0
