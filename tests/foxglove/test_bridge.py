"""`viena foxglove` against the simulated car, seen through a Foxglove WebSocket client
written in the tests (foxglove_client.py): its channels, its messages checked against
the schemas it advertises, the e-stop, a client that stops reading, and shutdown."""
from __future__ import annotations

import json
import queue
import re
import signal
import time

import pytest
from foxglove_client import FoxgloveClient, decoder
from vienatest import Processes, free_port, open_session, start_router, wait_for_line, wait_for_subscriber

from viena.common.paths import compose_dir
from viena.common.samples.fix import FIX
from viena.common.samples.truth import TRUTH
from viena.foxglove import QUEUE_SAMPLES

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=12)]  # the whole simulated car, as processes
CAR = "foxtest"
ROOT = f"viena/{CAR}"
UNITS = ("gnss0", "gnss1")
HEALTH_OF = ["sim", *(f"gnss/{u}" for u in UNITS), "imu/razor0", "estimator"]
SAMPLE_KEYS = [f"{ROOT}/sim/truth", *(f"{ROOT}/gnss/{u}/fix" for u in UNITS), f"{ROOT}/imu/razor0/sample",
               f"{ROOT}/estimator/state"]
DERIVED = [*(f"{ROOT}/foxglove/gnss/{u}/location" for u in UNITS), f"{ROOT}/foxglove/estimator/location",
           f"{ROOT}/foxglove/estimator/pose", f"{ROOT}/foxglove/sim/truth/location",
           f"{ROOT}/foxglove/sim/truth/pose", f"{ROOT}/foxglove/tf", f"{ROOT}/foxglove/log"]
BACKLOG = 64


def start_bridge(procs: Processes, router: str, *extra: str) -> tuple[object, int]:
    """`viena foxglove` on a free port; (process, port) once it serves."""
    proc = procs.python("-m", "viena.foxglove", "--connect", router, "--car", CAR, "--port", "0",
                        "--log-level", "WARNING", *extra)
    line = wait_for_line(proc.stderr, "serving", timeout=60)
    return proc, int(re.search(r"ws://127\.0\.0\.1:(\d+)", line).group(1))


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """Router, simulated car (twins, GNSS x2, IMU, estimator) and a bridge: (router, port, bridge)."""
    import os

    procs = Processes()
    saved = {k: os.environ.get(k) for k in ("VIENA_GNSS0_PORT", "VIENA_GNSS1_PORT", "VIENA_RAZOR0_PORT")}
    try:
        for name in saved:
            os.environ[name] = str(free_port())
        router = start_router(procs)
        common = ("--connect", router, "--car", CAR, "--config", str(compose_dir() / "sim.toml"),
                  "--log-level", "WARNING")
        procs.python("-m", "viena.services.sim.service", *common, "--device", "gnss0", "--device", "gnss1",
                     "--device", "razor0")
        for unit in UNITS:
            procs.python("-m", "viena.services.gnss.service", *common, "--unit", unit)
        procs.python("-m", "viena.services.imu.service", *common, "--unit", "razor0")
        procs.python("-m", "viena.services.estimator.service", *common)
        bridge, port = start_bridge(procs, router, "--backlog", str(BACKLOG))
        with FoxgloveClient(port) as client:               # the car is up once its keys are
            assert client.wait_for_topics(SAMPLE_KEYS + DERIVED[:-1], timeout=90), \
                sorted(c["topic"] for c in client.channels.values())
        yield router, port, bridge
    finally:
        procs.stop_all()
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def test_the_protocol_and_every_key_as_a_channel(car):
    _, port, _ = car
    with FoxgloveClient(port) as client:
        assert client.wait_for_topics(SAMPLE_KEYS + DERIVED[:-1])
        assert client.subprotocol == "foxglove.sdk.v1"           # = foxglove.websocket.v1, renamed
        assert client.server_info["name"] == f"viena {CAR}"
        fix = client.channel(f"{ROOT}/gnss/gnss0/fix")
        assert (fix["encoding"], fix["schemaEncoding"], fix["schemaName"]) == ("json", "jsonschema", FIX.name)
        assert json.loads(fix["schema"])["properties"]["lat_deg"] == {"type": "number"}
        location = client.channel(f"{ROOT}/foxglove/gnss/gnss0/location")
        assert (location["encoding"], location["schemaName"]) == ("protobuf", "foxglove.LocationFix")
        assert client.wait_for(lambda: client.services)
        assert set(client.services) == {"estop"}                  # the one thing a client may send


def test_locations_are_the_receivers_fixes_to_a_billionth_of_a_degree(car):
    router, port, _ = car
    fixes: queue.Queue = queue.Queue()
    with open_session(router) as session, FoxgloveClient(port) as client:
        sub = session.declare_subscriber(f"{ROOT}/gnss/*/fix", lambda s: fixes.put(FIX.decode(s.payload.to_bytes())))
        client.wait_for_topics(DERIVED[:2])
        channels = [client.channel(t) for t in DERIVED[:2]]
        client.subscribe(channels)
        got = client.collect(lambda m: len(m) >= 40, timeout=30)
        time.sleep(0.5)                                           # the fixes' own samples too
        sub.undeclare()
    heard = {}
    while not fixes.empty():
        f = fixes.get()
        heard[(f["unit"], f["t"])] = f
    matched = 0
    for message in got:
        loc = decoder(message.channel)(message.payload)
        unit = message.channel["topic"].split("/")[-2]
        fix = heard.get((unit, loc.timestamp.seconds * 10**9 + loc.timestamp.nanos))
        if fix is None:
            continue                                              # heard before our subscriber
        assert loc.frame_id == unit
        assert abs(loc.latitude - fix["lat_deg"]) < 1e-9 and abs(loc.longitude - fix["lon_deg"]) < 1e-9
        assert abs(loc.altitude - fix["height_m"]) < 1e-6
        matched += 1
    assert matched >= 30, (matched, len(got))
    assert {m.channel["topic"] for m in got} == set(DERIVED[:2])


def test_every_message_passes_the_schema_its_channel_advertises(car):
    _, port, _ = car
    with FoxgloveClient(port) as client:
        # health comes once a second, each program's first some time after it starts
        client.wait_for_topics(SAMPLE_KEYS + [f"{ROOT}/{p}/health" for p in HEALTH_OF])
        health = {c["topic"] for c in client.channels.values() if c["topic"].endswith("/health")}
        assert len(health) >= 5                                   # sim, gnss x2, imu, estimator
        channels = list(client.channels.values())
        client.subscribe(channels)
        want = set(SAMPLE_KEYS + DERIVED[:-1]) | health
        got = client.collect(lambda m: want <= {x.channel["topic"] for x in m}, timeout=30)
    assert want <= {m.channel["topic"] for m in got}
    decoders = {c["id"]: decoder(c) for c in channels}
    for message in got:
        decoders[message.channel["id"]](message.payload)          # raises if it does not pass
    truth = [json.loads(m.payload) for m in got if m.channel["topic"] == f"{ROOT}/sim/truth"]
    assert all(TRUTH.validate(t) for t in truth)                  # and viena's own check agrees


def test_the_estop_service_puts_on_the_steering_estop_key(car):
    router, port, _ = car
    heard: queue.Queue = queue.Queue()
    with open_session(router) as session, FoxgloveClient(port) as client:
        sub = session.declare_subscriber(f"{ROOT}/steering/estop", lambda s: heard.put(
            (s.payload.to_bytes(), str(s.encoding))))
        with open_session(router) as other:           # the router knows the subscriber: a put reaches it
            assert wait_for_subscriber(other, f"{ROOT}/steering/estop")
        assert client.wait_for(lambda: "estop" in client.services)
        encoding, answer = client.call("estop", b'{"reason": "test"}')
        payload, zenoh_encoding = heard.get(timeout=10)
        sub.undeclare()
    assert encoding == "json" and json.loads(answer) == {"status": "sent", "key": f"{ROOT}/steering/estop"}
    assert json.loads(payload)["reason"] == "test" and zenoh_encoding.startswith("application/json")


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def test_a_client_that_stops_reading_slows_neither_the_car_nor_other_clients(car):
    router, port, bridge = car
    truth_seqs: list[tuple[int, int]] = []
    with open_session(router) as session, FoxgloveClient(port, receive_buffer=4096) as slow, \
            FoxgloveClient(port) as fast:
        sub = session.declare_subscriber(f"{ROOT}/sim/truth", lambda s: truth_seqs.append(
            (TRUTH.decode(s.payload.to_bytes())["seq"], time.monotonic_ns())))
        for client in (slow, fast):
            client.wait_for_topics(SAMPLE_KEYS + DERIVED[:-1])
        slow.subscribe(list(slow.channels.values()))              # everything, then reads nothing
        fast.subscribe([fast.channel(f"{ROOT}/sim/truth")])
        fast.messages(2.0)
        before_mb = rss_mb(bridge.pid)
        t0 = time.monotonic_ns()
        during = fast.messages(10.0)                              # the slow one reads nothing for 10 s
        t1 = time.monotonic_ns()
        after_mb = rss_mb(bridge.pid)
        sub.undeclare()
        # the newest message read is a fresh one (the last, not any: looking through every
        # message read so far, each time, made the client slower than the car and never fresh)
        again = slow.collect(lambda m: bool(m) and m[-1].log_time > time.time_ns() - 1e9, timeout=20)
    # the car: its truth went on at its rate while the slow client stalled (seq counts them)
    stalled = [seq for seq, at in truth_seqs if t0 <= at <= t1]
    print(f"stalled 10 s: truth samples {len(stalled)}, fast client {len(during)}, bridge RSS "
          f"{before_mb:.1f} -> {after_mb:.1f} MB, slow client read {len(again)} messages after")
    assert len(stalled) > 500 and len(stalled) >= 0.99 * (stalled[-1] - stalled[0] + 1)
    # another client got the truth as usual (it is JSON, seq in it)
    fast_seqs = [json.loads(m.payload)["seq"] for m in during]
    assert len(fast_seqs) >= 0.9 * len(stalled)
    # the bridge's memory: at most its queues' worth (samples waiting, messages per client)
    bound_mb = (QUEUE_SAMPLES + 2 * BACKLOG) * 8 / 1024 + 8
    assert after_mb - before_mb < bound_mb, (before_mb, after_mb)
    # and the slow client, once it reads again, is still connected and live
    assert again and bridge.poll() is None


def test_sigterm_and_sigint_stop_the_bridge_cleanly(car):
    router, _, _ = car
    procs = Processes()
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            proc, port = start_bridge(procs, router)
            with FoxgloveClient(port) as client:
                assert client.wait_for_topics(SAMPLE_KEYS[:1])
                client.subscribe([client.channel(SAMPLE_KEYS[0])])
                assert client.collect(lambda m: len(m) > 10)       # within 30 s: a busy machine is slow
                proc.send_signal(sig)
                assert proc.wait(timeout=5) == 0, proc.stderr.read()     # design notes: within 2 s
    finally:
        procs.stop_all()
