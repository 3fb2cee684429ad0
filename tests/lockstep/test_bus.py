"""The in-memory bus: zenoh's publish, subscribe, query and liveliness surface as viena's
services use it, on the wall clock (and once on the virtual one)."""
from __future__ import annotations

import threading

import msgpack
import pytest
import zenoh
from vienatest import wait_until

from viena.common import clock
from viena.common.lockstep.bus import MemoryBus
from viena.common.lockstep.scheduler import VirtualClock

NONE = zenoh.ConsolidationMode.NONE
#: long enough that a test that waited it out by mistake fails by its Timeout reply, not by the clock
NEVER_S = 30.0


@pytest.fixture
def new_bus():
    """MemoryBus(...), closed after the test (their callback threads end)."""
    made: list[MemoryBus] = []
    yield lambda **options: made.append(MemoryBus(**options)) or made[-1]
    for bus in made:
        bus.close()


@pytest.fixture
def bus(new_bus):
    return new_bus()


def payloads(replies) -> list:
    return [r.ok.payload.to_bytes() if r.ok is not None else ("err", r.err.payload.to_bytes()) for r in replies]


# -- publish and subscribe ---------------------------------------------------------------------
def test_puts_reach_the_subscribers_whose_key_expressions_match(bus):
    car, tool = bus.session("car"), bus.session("tool")
    got = {key: [] for key in ("viena/*/imu/imu0/sample", "viena/**", "viena/elettra/gnss/*/fix", "other/**")}
    for key, seen in got.items():
        tool.declare_subscriber(key, lambda s, seen=seen: seen.append(str(s.key_expr)))
    own = []
    car.declare_subscriber("viena/elettra/**", lambda s: own.append(str(s.key_expr)))   # its own puts too
    for key in ("viena/elettra/imu/imu0/sample", "viena/elettra/gnss/gnss0/fix", "viena/elettra/gnss/a/b/fix"):
        car.put(key, b"x")
    assert wait_until(lambda: len(got["viena/**"]) == 3 and len(own) == 3, 5)
    assert got["viena/*/imu/imu0/sample"] == ["viena/elettra/imu/imu0/sample"]
    assert got["viena/elettra/gnss/*/fix"] == ["viena/elettra/gnss/gnss0/fix"]     # * is one chunk
    assert got["other/**"] == []
    with pytest.raises(zenoh.ZError):
        car.put("viena//x", b"x")                      # zenoh's own key checks


def test_payload_bytes_and_encodings_arrive_as_sent(bus):
    car, tool = bus.session("car"), bus.session("tool")
    got = []
    tool.declare_subscriber("k/*", lambda s: got.append((str(s.key_expr), str(s.encoding), s.payload.to_bytes(),
                                                          s.kind)))
    plain = car.declare_publisher("k/plain")
    typed = car.declare_publisher("k/typed", encoding=zenoh.Encoding("application/msgpack"))
    data = bytearray(msgpack.packb({"a": 1}))
    typed.put(data)
    data[:] = b"changed after the put"                 # the sample carries a copy
    plain.put(b"\x00\xff")
    typed.put(b"{}", encoding=zenoh.Encoding("application/json"))
    car.put("k/session", b"t", encoding="text/plain")
    assert wait_until(lambda: len(got) == 4, 5)
    put = zenoh.SampleKind.PUT
    assert got == [("k/typed", "application/msgpack", msgpack.packb({"a": 1}), put),
                   ("k/plain", "zenoh/bytes", b"\x00\xff", put),
                   ("k/typed", "application/json", b"{}", put),
                   ("k/session", "text/plain", b"t", put)]


def test_a_ring_channel_keeps_the_newest_sample(new_bus):
    bus = new_bus(one_thread_per_session=True)       # the ring is filled before `got` hears of it
    car, pilot = bus.session("car"), bus.session("pilot")
    ring = pilot.declare_subscriber("estimator/state", zenoh.handlers.RingChannel(1))
    assert ring.try_recv() is None
    got = []
    pilot.declare_subscriber("estimator/state", got.append)
    for n in range(5):
        car.put("estimator/state", bytes([n]))
    assert wait_until(lambda: len(got) == 5, 5)
    assert ring.try_recv().payload.to_bytes() == b"\x04"
    assert ring.try_recv() is None
    car.put("estimator/state", b"\x05")
    assert ring.recv().payload.to_bytes() == b"\x05"                # waits for it
    ring.undeclare()
    with pytest.raises(zenoh.ZError):
        ring.try_recv()


def test_callbacks_run_on_their_own_threads_in_order_never_the_putters(bus):
    car, tool = bus.session("car"), bus.session("tool")
    lock = threading.Lock()
    seen: list = []

    def on_sample(sample):
        with lock:                      # the putter holds it while it puts: inline, this would deadlock
            seen.append((sample.payload.to_bytes(), threading.get_ident()))

    tool.declare_subscriber("k", on_sample)
    with lock:
        for n in range(100):
            car.put("k", str(n).encode())
    assert wait_until(lambda: len(seen) == 100, 5)
    assert [data for data, _ in seen] == [str(n).encode() for n in range(100)]
    assert {ident for _, ident in seen} != {threading.get_ident()}


def test_a_callback_that_raises_is_logged_and_the_next_sample_still_comes(bus, caplog):
    car = bus.session("car")
    got = []

    def fragile(sample):
        if sample.payload.to_bytes() == b"bad":
            raise ValueError("boom")
        got.append(sample.payload.to_bytes())

    car.declare_subscriber("k", fragile)
    car.put("k", b"bad")
    car.put("k", b"good")
    assert wait_until(lambda: got == [b"good"], 5)
    assert "ValueError: boom" in caplog.text


def test_one_thread_per_session_delivers_the_sessions_samples_in_put_order(new_bus):
    bus = new_bus(one_thread_per_session=True)
    car, tool = bus.session("car"), bus.session("tool")
    seen = []
    tool.declare_subscriber("a/*", lambda s: seen.append(("a*", s.payload.to_bytes())))
    tool.declare_subscriber("**", lambda s: seen.append(("**", s.payload.to_bytes())))
    for n in range(3):
        car.put("a/b", bytes([n]))
    assert wait_until(lambda: len(seen) == 6, 5)
    assert seen == [(sub, bytes([n])) for n in range(3) for sub in ("a*", "**")]


# -- queries -------------------------------------------------------------------------------------
def test_a_get_collects_every_reply_of_every_matching_queryable(new_bus):
    bus = new_bus(one_thread_per_session=True)       # one thread: the replies' order is the queryables'
    steering, client = bus.session("steering"), bus.session("client")
    asked = []

    def describe(query):
        asked.append((str(query.key_expr), query.payload, query.encoding))
        query.reply("viena/car/steering/arm", b"described")

    def command(query):
        asked.append((str(query.key_expr), query.payload.to_bytes(), str(query.encoding)))
        query.reply(query.key_expr, b"first", encoding=zenoh.Encoding("application/json"))
        query.reply(query.key_expr, b"second")

    steering.declare_queryable("viena/car/steering/*", describe)
    steering.declare_queryable("viena/car/steering/arm", command)
    replies = list(client.get("viena/car/steering/arm", payload=b'{"arm": true}', encoding="application/json",
                              timeout=NEVER_S, consolidation=NONE))
    assert payloads(replies) == [b"described", b"first", b"second"]
    assert [str(r.ok.encoding) for r in replies] == ["zenoh/bytes", "application/json", "zenoh/bytes"]
    assert {str(r.replier_id.zid) for r in replies} == {"mem-steering-1"} == {str(steering.zid())}
    assert asked[1] == ("viena/car/steering/arm", b'{"arm": true}', "application/json")
    # a question without payload has none, and no encoding; a wildcard question keeps its key
    asked.clear()
    list(client.get("viena/car/steering/*", timeout=NEVER_S, consolidation=NONE))
    assert asked[0] == ("viena/car/steering/*", None, None)


def test_by_default_a_get_keeps_the_last_reply_per_key(bus):
    steering, client = bus.session("steering"), bus.session("client")
    steering.declare_queryable("k", lambda q: (q.reply("k", b"1"), q.reply("k", b"2")))
    assert payloads(client.get("k", timeout=NEVER_S)) == [b"2"]                  # zenoh's AUTO: LATEST
    assert payloads(client.get("k", timeout=NEVER_S, consolidation=NONE)) == [b"1", b"2"]


def test_the_reply_goes_when_the_last_reference_to_the_query_goes(bus):
    """As the steering's controller and the pilot's inbox do: keep the query, answer on
    another thread, let it go; the getter waits for exactly that."""
    steering, client = bus.session("steering"), bus.session("client")
    jobs = clock.Queue()

    def worker():
        while (query := jobs.get()) is not None:
            clock.sleep(0.05)
            query.reply(query.key_expr, b"answer")
            del query                            # the last reference: the query is finalized

    clock.Thread(worker).start()
    steering.declare_queryable("k", jobs.put)
    assert payloads(client.get("k", timeout=NEVER_S, consolidation=NONE)) == [b"answer"]
    jobs.put(None)


def test_drop_and_with_finalize_a_query_and_replying_after_drop_raises(bus):
    steering, client = bus.session("steering"), bus.session("client")
    errors = []
    kept = []

    def drops(query):
        query.reply("a", b"before")
        query.drop()
        try:
            query.reply("a", b"after")
        except zenoh.ZError as exc:
            errors.append(str(exc))
        kept.append(query)                       # still referenced: drop() was what ended it

    def with_block(query):
        with query:
            query.reply("b", b"inside")
        kept.append(query)

    steering.declare_queryable("a", drops)
    steering.declare_queryable("b", with_block)
    assert payloads(client.get("a", timeout=NEVER_S)) == [b"before"]
    assert errors == ["Dropped query"]
    assert payloads(client.get("b", timeout=NEVER_S)) == [b"inside"]


def test_a_query_held_past_the_timeout_ends_the_get_with_a_timeout_error(bus):
    steering, client = bus.session("steering"), bus.session("client")
    held = []

    def hold(query):
        query.reply(query.key_expr, b"early")
        held.append(query)

    steering.declare_queryable("k", hold)
    replies = list(client.get("k", timeout=0.1, consolidation=NONE))
    assert payloads(replies) == [b"early", ("err", b"Timeout")]
    assert str(replies[1].err.encoding) == "zenoh/string" and replies[1].replier_id is None
    held[0].reply("k", b"late")                   # lost, as zenoh loses it: no error
    held.clear()


def test_a_reply_must_be_on_a_key_the_question_covers_and_errors_are_replies(bus):
    steering, client = bus.session("steering"), bus.session("client")
    refused = []

    def answer(query):
        try:
            query.reply("elsewhere", b"x")
        except zenoh.ZError as exc:
            refused.append(str(exc))
        query.reply_err(b"bad question")

    steering.declare_queryable("k", answer)
    replies = list(client.get("k", timeout=NEVER_S))
    assert replies[0].ok is None and replies[0].err.payload.to_bytes() == b"bad question"
    assert str(replies[0].replier_id.zid) == "mem-steering-1"
    assert refused and "does not intersect" in refused[0]


def test_a_get_without_queryables_ends_at_once(bus):
    client = bus.session("client")
    assert list(client.get("nobody/home", timeout=NEVER_S)) == []      # no Timeout reply: it did not wait


# -- liveliness ----------------------------------------------------------------------------------
def test_liveliness_tokens_are_found_while_alive_and_watched(bus):
    gnss, monitor = bus.session("gnss"), bus.session("monitor")
    watched = []
    token = gnss.liveliness().declare_token("viena/car/alive/gnss/gnss0")
    monitor.liveliness().declare_subscriber("viena/car/alive/**", lambda s: watched.append(
        (str(s.key_expr), s.kind)), history=True)
    other = gnss.liveliness().declare_token("viena/car/alive/gnss/gnss1")
    gnss.liveliness().declare_token("viena/car/alive/gnss/forgotten")      # garbage at once: gone, as in zenoh

    def alive(key="viena/car/alive/**"):
        return [str(r.ok.key_expr) for r in monitor.liveliness().get(key, timeout=NEVER_S)]

    assert alive() == ["viena/car/alive/gnss/gnss0", "viena/car/alive/gnss/gnss1"]
    assert alive("viena/car/alive/imu/*") == []
    token.undeclare()
    with pytest.raises(zenoh.ZError):
        token.undeclare()
    assert alive() == ["viena/car/alive/gnss/gnss1"]
    gnss.close()                                   # tokens go with their session
    assert alive() == []
    other.undeclare()                              # after close: nothing to do
    put, delete = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    forgotten = "viena/car/alive/gnss/forgotten"
    assert wait_until(lambda: len(watched) == 6, 5)
    assert watched == [("viena/car/alive/gnss/gnss0", put), ("viena/car/alive/gnss/gnss1", put),
                       (forgotten, put), (forgotten, delete),
                       ("viena/car/alive/gnss/gnss0", delete), ("viena/car/alive/gnss/gnss1", delete)]


# -- the end of a session ------------------------------------------------------------------------
def test_after_close_calls_raise_and_undeclaring_does_nothing(bus):
    car = bus.session("car")
    pub = car.declare_publisher("k")
    sub = car.declare_subscriber("k", lambda s: None)
    car.close()
    assert car.is_closed() and str(car.zid()) == "mem-car-1"
    for call in (lambda: car.put("k", b"x"), lambda: pub.put(b"x"), lambda: car.declare_subscriber("k", print),
                 lambda: car.get("k"), lambda: car.liveliness().declare_token("k"),
                 lambda: car.liveliness().get("k")):
        with pytest.raises(zenoh.ZError, match="session closed"):
            call()
    sub.undeclare()
    pub.undeclare()
    car.close()
    assert str(bus.session("car").zid()) == "mem-car-2"           # the program started again


@pytest.mark.parametrize("end", ["close", "kill"])
def test_close_lets_queued_callbacks_run_and_kill_does_not(bus, end):
    car, tool = bus.session("car"), bus.session("tool")
    inside, gate, got = threading.Event(), threading.Event(), []

    def on_sample(sample):
        inside.set()
        gate.wait(5)
        got.append(sample.payload.to_bytes())

    tool.declare_subscriber("k", on_sample)
    car.put("k", b"1")
    car.put("k", b"2")
    assert inside.wait(5)                      # 1 is in the callback, 2 waits in its queue
    getattr(tool, end)()
    car.put("k", b"3")                         # after the end: never delivered
    gate.set()
    if end == "close":
        assert wait_until(lambda: got == [b"1", b"2"], 5)                # as zenoh's callback thread drains
    else:
        assert wait_until(lambda: got == [b"1"], 5)
        assert not wait_until(lambda: len(got) > 1, 0.2)


@pytest.mark.parametrize("end", ["close", "kill"])
def test_queries_a_closed_or_killed_program_held_end_at_once(bus, end):
    steering, client = bus.session("steering"), bus.session("client")
    held = []
    steering.declare_queryable("k", held.append)
    replies = client.get("k", timeout=NEVER_S, consolidation=NONE)
    assert wait_until(lambda: held, 5)
    getattr(steering, end)()
    assert list(replies) == []                     # finalized as dropped: no reply, no timeout
    with pytest.raises(zenoh.ZError, match="session closed"):
        held[0].reply("k", b"too late")


def test_options_the_bus_does_not_have_are_refused_by_name(bus):
    car = bus.session("car")
    with pytest.raises(NotImplementedError, match="attachment"):
        car.put("k", b"x", attachment=b"a")
    with pytest.raises(NotImplementedError, match="handler"):
        car.declare_subscriber("k", zenoh.handlers.FifoChannel(4))
    with pytest.raises(NotImplementedError, match="parameters"):
        car.get("k?x=1")
    with pytest.raises(NotImplementedError, match="complete"):
        car.get("k", target=zenoh.QueryTarget.ALL_COMPLETE)
    car.put("k", b"x", congestion_control=zenoh.CongestionControl.BLOCK)   # QoS: accepted, nothing to do


def test_latency_delays_every_delivery(new_bus):
    bus = new_bus(latency_s=0.05)
    car, tool = bus.session("car"), bus.session("tool")
    arrived = []
    tool.declare_subscriber("k", lambda s: arrived.append(clock.monotonic()))
    tool.declare_queryable("q", lambda q: q.reply("q", b"r"))
    sent = clock.monotonic()
    car.put("k", b"x")
    assert payloads(car.get("q", timeout=NEVER_S)) == [b"r"]
    asked = clock.monotonic() - sent
    assert wait_until(lambda: arrived, 5)
    assert arrived[0] - sent >= 0.05 and asked >= 0.1       # there (0.05) and back (0.05)


# -- viena's own code on the bus -----------------------------------------------------------------
def steering_answers(session, granted: list):
    """A steering service's command queryables as far as its client sees them: the
    answers of viena.common.service.reply_to, in the encoding asked."""
    from viena.common.service import query_payload, reply_to

    def on_arm(query):
        data, encoding = query_payload(query)
        reply_to(query, {"status": "accepted", "lease": "L"}, encoding, data)
        granted.append(str(session.zid()))

    def on_setpoint(query):
        data, encoding = query_payload(query)
        reply_to(query, {"status": "accepted", "target_deg": 1.0}, encoding, data)

    session.declare_queryable("viena/elettra/steering/arm", on_arm)
    session.declare_queryable("viena/elettra/steering/setpoint", on_setpoint)


def test_the_steering_client_talks_to_one_steering_and_sees_a_second(bus):
    from viena.services.steering.client import ConflictingReplies, SteeringClient

    granted: list = []
    steering_answers(bus.session("steering"), granted)
    client = SteeringClient(bus.session("pilot"), "elettra", timeout_s=NEVER_S)
    assert client.arm() == {"status": "accepted", "lease": "L"}
    assert client.replier == "mem-steering-1" == granted[0]
    assert client.setpoint(1.0)["status"] == "accepted"
    steering_answers(bus.session("impostor"), granted)
    with pytest.raises(ConflictingReplies, match="mem-impostor-1"):
        client.setpoint(1.0)


def test_a_service_serves_on_the_bus_with_its_token_and_health(bus):
    from viena.common.samples.health import HEALTH
    from viena.common.service import Service, build_parser

    class Toy(Service):
        name = "toy"

    def health_of(sample):
        return HEALTH.decode(sample.payload.to_bytes())["service"] == "toy"

    observer = bus.session("observer")
    health = observer.declare_subscriber("viena/elettra/toy/health", zenoh.handlers.RingChannel(1))
    toy = Toy(build_parser(Toy).parse_args([]))
    done = []
    clock.Thread(lambda: done.append(toy.serve(bus.session("toy")))).start()
    assert wait_until(lambda: (sample := health.try_recv()) is not None and health_of(sample), 5)
    alive = [str(r.ok.key_expr) for r in observer.liveliness().get("viena/elettra/alive/**")]
    assert alive == ["viena/elettra/alive/toy"]
    second = Toy(build_parser(Toy).parse_args([]))
    assert second.serve(bus.session("toy")) == 2                    # the same unit runs already
    toy.stopping.set()
    assert wait_until(lambda: done == [0], 5)
    assert list(observer.liveliness().get("viena/elettra/alive/**")) == []
    assert toy.session.is_closed()


# -- on the virtual clock ------------------------------------------------------------------------
def test_on_the_virtual_clock_deliveries_and_timeouts_take_virtual_time_only():
    bus = MemoryBus(latency_s=0.001)
    with VirtualClock(watchdog_s=5.0) as vc:
        car, tool = bus.session("car"), bus.session("tool")
        seen, held = [], []
        tool.declare_subscriber("k", lambda s: seen.append((clock.monotonic(), s.payload.to_bytes())))
        tool.declare_queryable("q", held.append)
        t0 = clock.monotonic()
        car.put("k", b"x")
        replies = list(car.get("q", timeout=60.0, consolidation=NONE))      # 60 s, in no real time
        assert payloads(replies) == [("err", b"Timeout")]
        assert clock.monotonic() - t0 == pytest.approx(60.0)
        assert seen == [(pytest.approx(t0 + 0.001), b"x")]
        held.clear()
        tool.kill()
        bus.close()
        vc.run_for(1.0)
        assert vc.errors == [] and vc.threads() == [f"driver/{threading.current_thread().name}"]   # the callback threads ended
