"""`viena export --format foxglove`: an MCAP file that the `mcap` library reads, whose every
channel has an encoding Foxglove knows and whose every message passes its own schema."""
from __future__ import annotations

import json
from collections import Counter

import msgpack
import pytest
from foxglove_client import as_advertised, decoder, read_all
from laptop_helpers import FIX_ENCODING, viena, write_drive
from mcap.reader import make_reader

from viena.common.recording import RecordingWriter

FIX_KEY = "viena/elettra/gnss/gnss0/fix"
KNOWN = {("json", "jsonschema"), ("json", ""), ("protobuf", "protobuf")}


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    return path, write_drive(path, seconds=10.0)


@pytest.fixture(scope="module")
def exported(drive, tmp_path_factory):
    path, written = drive
    out = tmp_path_factory.mktemp("fox") / "drive-fox.mcap"
    result = viena("export", path, "--format", "foxglove", "-o", out)
    assert result.returncode == 0, result.stderr
    return out, written


def test_every_channel_has_a_known_encoding_and_every_message_passes_its_schema(exported):
    out, written = exported
    summary, messages = read_all(out)
    assert summary is not None and summary.statistics.message_count == len(messages)
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        assert (channel.message_encoding, schema.encoding if schema else "") in KNOWN, channel.topic
    decoders = {}
    for schema, channel, message in messages:
        decode = decoders.get(channel.id)
        if decode is None:
            decode = decoders[channel.id] = decoder(as_advertised(channel, schema))
        decode(message.data)                            # raises if it does not pass
    per_topic = Counter(channel.topic for _, channel, _ in messages)
    for key, samples in written.items():                # every sample, as JSON on its key
        assert per_topic[key] == len(samples)
    valid = [f for f in written[FIX_KEY] if f["valid"]]
    assert per_topic["viena/elettra/foxglove/gnss/gnss0/location"] == len(valid) < len(written[FIX_KEY])
    assert per_topic["viena/elettra/foxglove/sim/truth/pose"] == len(written["viena/elettra/sim/truth"])
    assert per_topic["viena/elettra/foxglove/tf"] == (len(written["viena/elettra/sim/truth"])
                                                      + len(written["viena/elettra/estimator/state"]))


def test_json_messages_hold_the_samples_and_locations_the_fixes(exported):
    out, written = exported
    _, messages = read_all(out)
    fixes = [json.loads(m.data) for _, c, m in messages if c.topic == FIX_KEY]
    assert fixes == [{k: v for k, v in f.items() if v is not None}      # every field, every digit
                     for f in written[FIX_KEY]]                         # (nil optional ones left out)
    schema = next(s for s, c, _ in messages if c.topic == "viena/elettra/foxglove/gnss/gnss0/location")
    locations = [decoder(as_advertised(c, s))(m.data) for s, c, m in messages
                 if c.topic == "viena/elettra/foxglove/gnss/gnss0/location"]
    assert schema.name == "foxglove.LocationFix"
    by_t = {f["t"]: f for f in written[FIX_KEY]}
    for loc in locations:
        fix = by_t[loc.timestamp.seconds * 10**9 + loc.timestamp.nanos]
        assert abs(loc.latitude - fix["lat_deg"]) < 1e-9 and abs(loc.longitude - fix["lon_deg"]) < 1e-9
    log_times = [m.log_time for _, c, m in messages if c.topic == FIX_KEY]
    assert log_times == [f["t"] + 2_000_000 for f in written[FIX_KEY]]     # the recorded log times


def test_samples_that_fail_their_schema_are_left_out_and_said(tmp_path):
    path = tmp_path / "bad.mcap"
    writer = RecordingWriter(path)
    good = {"t": 1_717_236_000_000_000_000, "seq": 1, "service": "sim", "uptime_s": 1.0, "rates_hz": {},
            "counts": {}, "errors": {}}
    enc = "application/msgpack;viena.health/1"
    writer.write("viena/elettra/sim/health", enc, 1, msgpack.packb(good))
    writer.write("viena/elettra/sim/health", enc, 2, msgpack.packb({**good, "uptime_s": "long"}))
    writer.write("viena/elettra/typed", "application/json", 3, b'{"text": "from a person"}')
    writer.write(FIX_KEY, FIX_ENCODING, 4, b"\xc1 not msgpack")
    writer.close()
    result = viena("export", path, "--format", "foxglove")
    assert result.returncode == 0, result.stderr
    assert "1 samples on viena/elettra/sim/health failed their schema: left out" in result.stderr
    _, messages = read_all(tmp_path / "bad-foxglove.mcap")
    assert [(c.topic, json.loads(m.data)) for _, c, m in messages] == [
        ("viena/elettra/sim/health", good), ("viena/elettra/typed", {"text": "from a person"})]


def test_a_recorder_writes_a_foxglove_file_live(session, tmp_path):
    """`viena record --foxglove`: the recorder, given a FoxgloveWriter for its writer."""
    from vienatest import wait_until

    from viena.common.samples.truth import TRUTH
    from viena.foxglove_export import FoxgloveWriter
    from viena.record import Recorder
    from viena.services.sim.model.car import SimCar
    from viena.services.sim.model.truth import truth_sample

    writer = FoxgloveWriter(tmp_path / "live.mcap", metadata={"car": "elettra"})
    recorder = Recorder(session, ["viena/elettra/**"], writer)
    recorder.start()
    car, sent = SimCar(), []
    for _ in range(50):
        sample = truth_sample(car.step(0.01))
        session.put("viena/elettra/sim/truth", TRUTH.encode(sample), encoding=TRUTH.encoding)
        sent.append(sample)
    wait_until(lambda: writer.samples == len(sent), 10)
    path = recorder.stop()
    assert path == tmp_path / "live.mcap" and not (tmp_path / "live.mcap.part").exists()
    summary, messages = read_all(path)
    truth = [json.loads(m.data) for _, c, m in messages if c.topic == "viena/elettra/sim/truth"]
    assert truth == sent
    assert sum(1 for _, c, _ in messages if c.topic == "viena/elettra/foxglove/tf") == len(sent)
    with open(path, "rb") as f:
        assert dict(next(make_reader(f).iter_metadata()).metadata) == {"car": "elettra"}
