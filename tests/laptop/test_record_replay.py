"""`viena record` and `viena replay` against the real simulated car, through real routers."""
from __future__ import annotations

import queue
import signal
import time

import msgpack
import pytest
from laptop_helpers import SIM_HEALTH_KEY, TRUTH_KEY, VIENA, start_sim, viena, wait_for_samples
from mcap.reader import make_reader
from vienatest import Processes, open_session, start_router, wait_for_line, wait_for_subscriber, wait_until

from viena.common.recording import Recording

pytestmark = pytest.mark.slow  # a router, the sim and the CLI as processes


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """A few seconds of the simulated car (three of its 1 Hz health samples), recorded by
    `viena record` and stopped with Ctrl-C (SIGINT); plus a fresh router with nothing on
    it, for replays."""
    procs = Processes()
    tmp = tmp_path_factory.mktemp("drive")
    try:
        router = start_router(procs)
        start_sim(procs, router, tmp)
        out = tmp / "drive.mcap"
        with open_session(router) as session:
            wait_for_samples(session, SIM_HEALTH_KEY)        # the sim is up for a second
            rec = procs.start(*VIENA, "record", "--connect", router, "-o", out, "-q")
            wait_for_line(rec.stderr, "recording viena/**")
            assert wait_for_subscriber(session, SIM_HEALTH_KEY)      # the router knows the recorder
            health = queue.Queue()
            sub = session.declare_subscriber(SIM_HEALTH_KEY, health.put)
            assert wait_until(lambda: health.qsize() >= 3, 10)     # the recorder has two, at least
            sub.undeclare()
        rec.send_signal(signal.SIGINT)
        _, err = rec.communicate(timeout=20)
        assert rec.returncode == 0, err
        yield out, err, start_router(procs)
    finally:
        procs.stop_all()


def test_record_keeps_every_sample_the_sim_counts(drive):
    out, err, _ = drive
    assert "recorded" in err and str(out) in err
    assert out.exists() and not out.with_name("drive.mcap.part").exists()

    recording = Recording(out)
    samples = list(recording.messages())
    assert recording.complete and recording.report() == []
    truth = [msgpack.unpackb(m.data) for m in samples if m.key == TRUTH_KEY]
    health = [msgpack.unpackb(m.data) for m in samples if m.key == SIM_HEALTH_KEY]
    assert len(health) >= 2
    seqs = [s["seq"] for s in truth]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a truth sample was lost"
    # The sim's own counter: every truth sample it had published when it sent its last
    # health, from the first one the recorder heard, is in the file.
    published = health[-1]["counts"]["truth"]
    assert published >= seqs[0]
    assert set(range(seqs[0], published + 1)) <= set(seqs)
    assert health[-1]["errors"] == {}

    for m in samples:
        assert m.publish_time == msgpack.unpackb(m.data)["t"]
    log_times = [m.log_time for m in samples]
    assert log_times == sorted(log_times)


def test_record_file_is_a_standard_mcap(drive):
    out, _, _ = drive
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        schemas = {s.id: s.name for s in summary.schemas.values()}
        assert channels[TRUTH_KEY].message_encoding == "msgpack"
        assert schemas[channels[TRUTH_KEY].schema_id] == "viena.sim.truth/1"
        assert schemas[channels[SIM_HEALTH_KEY].schema_id] == "viena.health/1"
        assert channels[TRUTH_KEY].metadata["zenoh_encoding"] == "application/msgpack;viena.sim.truth/1"
        n = sum(1 for _ in reader.iter_messages())
    assert n == summary.statistics.message_count > 100


def listen(session, keyexpr):
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(
        keyexpr, lambda s: got.put((str(s.key_expr), s.payload.to_bytes(), str(s.encoding),
                                    time.monotonic())))
    return sub, got


def drain(got: queue.Queue) -> list:
    out = []
    while not got.empty():
        out.append(got.get())
    return out


#: how much later than the rest the first replayed sample may reach this process
FIRST_DELIVERY_JITTER_S = 0.1


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_replay_reproduces_the_recording_with_its_timing(drive, rate):
    out, _, fresh = drive                            # no sim there: only what replay sends
    recorded = list(Recording(out).messages())
    with open_session(fresh) as s, open_session(fresh) as probe:
        sub, got = listen(s, "viena/**")
        assert wait_for_subscriber(probe, "viena/elettra/sim/truth")
        result = viena("replay", out, "--connect", fresh, "--rate", rate)
        wait_until(lambda: got.qsize() >= len(recorded), 5)
        sub.undeclare()
    assert result.returncode == 0, result.stderr
    replayed = drain(got)
    assert [(k, p, e) for k, p, e, _ in replayed] == [(m.key, m.data, m.encoding) for m in recorded]

    # Timing: replay never publishes a sample before its time, so the replayed span is at
    # least the recorded one (divided by the rate), less what the first sample's delivery
    # lost here (the times are this process's, on arrival: a busy machine once delivered it
    # 57 ms late, 0.64 s of a 0.69 s span at 4x; a replay at twice the rate would show
    # 0.35 s); an upper bound only guards against gross errors (this machine is shared).
    recorded_span = (recorded[-1].log_time - recorded[0].log_time) / 1e9 / rate
    replayed_span = replayed[-1][3] - replayed[0][3]
    assert replayed_span >= recorded_span * 0.98 - FIRST_DELIVERY_JITTER_S
    assert replayed_span < recorded_span + 1.5


def test_replay_renames_the_car_and_filters_keys(drive):
    out, _, fresh = drive
    health = [m for m in Recording(out).messages() if m.key == SIM_HEALTH_KEY]
    with open_session(fresh) as s, open_session(fresh) as probe:
        sub, got = listen(s, "viena/**")
        assert wait_for_subscriber(probe, "viena/twin/sim/health")
        result = viena("replay", out, "--connect", fresh, "--rate", 0, "--car", "twin",
                       "--keyexpr", "viena/elettra/*/health")
        wait_until(lambda: got.qsize() >= len(health), 5)
        sub.undeclare()
    assert result.returncode == 0, result.stderr
    replayed = drain(got)
    assert [k for k, *_ in replayed] == ["viena/twin/sim/health"] * len(health)
    assert [p for _, p, *_ in replayed] == [m.data for m in health]


def test_replay_loop_plays_again_until_stopped(procs, drive):
    out, _, fresh = drive
    n = sum(1 for m in Recording(out).messages() if m.key == TRUTH_KEY)
    with open_session(fresh) as s, open_session(fresh) as probe:
        sub, got = listen(s, TRUTH_KEY)
        assert wait_for_subscriber(probe, TRUTH_KEY)
        player = procs.start(*VIENA, "replay", out, "--connect", fresh, "--rate", 10, "--loop")
        wait_until(lambda: got.qsize() >= 2 * n + 1, 20)
        player.send_signal(signal.SIGINT)
        _, err = player.communicate(timeout=10)
        sub.undeclare()
    payloads = [p for _, p, *_ in drain(got)]
    assert len(payloads) > 2 * n
    assert payloads[n:2 * n] == payloads[:n]
    assert player.returncode == 0, err
    assert "passes" in err
