"""What a client's bytes on pilot/route and pilot/cmd can do to `viena-pilot` (issue 24,
item 6): a route nested 200,000 deep, one over the size limit, a flood of either. Each is
answered with its reason and counted, logged at most once per 10 s, never with a
traceback, and read off the control thread (services/pilot/inbox.py), which keeps its
mode and its route. The service runs in this process on a peer session of its own (no
router, no steering: an idle pilot needs neither), so caplog sees its log."""
from __future__ import annotations

import json
import logging
import threading

import msgpack
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st
from vienatest import wait_until

from viena.common.config import load_zenoh_config
from viena.common.payload import is_json_text
from viena.common.service import build_parser
from viena.services.pilot.inbox import Inbox, Request
from viena.services.pilot.model.pilot import Pilot
from viena.services.pilot.model.route import MAX_ROUTE_BYTES, RouteError, parse_route
from viena.services.pilot.service import PilotService

CAR = "viena/elettra"
NESTED = b"[" * 200_000
#: a valid route: two checkpoints 11 m apart
ROUTE = json.dumps([{"lat": 38.7369, "lon": -9.1395}, {"lat": 38.7370, "lon": -9.1395}]).encode()


@pytest.fixture
def pilot(caplog):
    """An idle PilotService on a peer session that listens nowhere; the same session asks."""
    caplog.set_level(logging.INFO, logger="viena")
    conf = load_zenoh_config(mode="peer")
    conf.insert_json5("listen/endpoints", "[]")
    service = PilotService(build_parser(PilotService).parse_args(["--car", "elettra"]))
    service.session = zenoh.open(conf)
    service.start()
    yield service
    service._shutdown()                       # stops the threads, closes the session


def ask(session, name: str, payload: bytes | None) -> dict:
    replies = [r.ok for r in session.get(f"{CAR}/pilot/{name}", payload=payload, timeout=5.0) if r.ok]
    assert len(replies) == 1
    data = replies[0].payload.to_bytes()
    return json.loads(data) if is_json_text(data) else msgpack.unpackb(data)


def no_traceback(caplog) -> None:
    assert not [r for r in caplog.records if r.exc_info], [r.getMessage() for r in caplog.records if r.exc_info]
    assert "Traceback" not in caplog.text


def test_a_deep_or_oversize_route_is_answered_with_its_reason_and_counted(pilot, caplog):
    session = pilot.session
    oversize = json.dumps([{"lat": 38.7369 + i * 1e-5, "lon": -9.1395} for i in range(10_000)]).encode()
    assert len(oversize) > MAX_ROUTE_BYTES
    answers = {
        "nested JSON": ask(session, "route", NESTED),
        "nested msgpack": ask(session, "route", b"\x91" * 200_000),
        "nested inside": ask(session, "route", b'{"points": ' + b"[" * 20 + b"]" * 20 + b"}"),
        "oversize": ask(session, "route", oversize),
        "huge number": ask(session, "route", b'[{"lat": 1' + b"0" * 400 + b', "lon": 1}, {"lat": 1, "lon": 1}]'),
    }
    assert {k: a["status"] for k, a in answers.items()} == dict.fromkeys(answers, "rejected")
    assert "nested deeper than 8 levels" in answers["nested JSON"]["reason"]
    assert "nested deeper than 8 levels" in answers["nested inside"]["reason"]
    assert "msgpack" in answers["nested msgpack"]["reason"]       # msgpack's own stack limit, 1024
    assert answers["oversize"]["reason"] == f"route of {len(oversize)} bytes: at most {MAX_ROUTE_BYTES} are read"
    assert answers["huge number"]["reason"].startswith("point 0: latitude is not finite (100000")
    assert len(answers["huge number"]["reason"]) < 120
    assert pilot.health.errors()["route_rejected"] == len(answers)
    assert pilot.pilot.mode == "idle" and pilot.pilot.route is None
    assert ask(session, "route", ROUTE)["status"] == "accepted"   # and it still takes a good one
    assert pilot.health.counts()["route"] == 1
    no_traceback(caplog)
    # throttled: the first refusal of a kind is logged, the next ones within 10 s are counted
    assert len([r for r in caplog.records if r.getMessage().startswith("refused: route")]) == 1


def test_a_flood_of_deep_routes_is_one_log_line_and_a_counter(pilot, caplog):
    for _ in range(200):
        pilot.session.put(f"{CAR}/pilot/route", NESTED)
    assert wait_until(lambda: sum(pilot.health.errors().get(k, 0) for k in ("route_rejected", "route_busy")) == 200,
                      20.0), pilot.health.errors()
    assert pilot.health.errors().get("internal") is None
    no_traceback(caplog)
    assert len([r for r in caplog.records if r.getMessage().startswith("refused: route")]) <= 2   # rejected, busy
    assert ask(pilot.session, "route", None) == {"status": "rejected", "reason": "no route yet"}
    assert ask(pilot.session, "route", ROUTE)["status"] == "accepted"


def test_bad_commands_are_answered_counted_and_never_start(pilot, caplog):
    session = pilot.session
    deep = b'{"cmd": ' + b"[" * 100 + b"]" * 100 + b"}"
    answers = [ask(session, "cmd", deep), ask(session, "cmd", b"start" * 300_000),
               ask(session, "cmd", msgpack.packb({"cmd": [[[[[[[[[["start"]]]]]]]]]]})),
               ask(session, "cmd", b"\x91" * 5000)]
    assert [a["status"] for a in answers] == ["rejected"] * 4
    assert "nested deeper than 8 levels" in answers[0]["reason"]
    assert answers[1]["reason"] == "cmd of 1500000 bytes: at most 4096 are read"
    assert all(a["mode"] == "idle" for a in answers)
    assert pilot.health.errors()["cmd_rejected"] == 4
    assert ask(session, "cmd", b"start") == {"status": "rejected", "reason": "no route: send one on pilot/route",
                                             "mode": "idle"}
    no_traceback(caplog)


def test_a_start_sent_before_an_estop_is_refused_after_it(pilot):
    """The estop is a flag the control thread reads each tick, never queued behind a flood;
    a start that came before it, decided after it, must not start anything."""
    query = FakeQuery(b"start")
    start = Request("cmd", "start", query, (None, b"start"), pilot.inbox.number())
    pilot._on_estop(None)
    pilot.commands._start(start)
    assert query.replies == [{"status": "rejected", "reason": "an estop came after this start", "mode": "idle"}]


class FakeQuery:
    """What Inbox needs of a zenoh.Query: its key and a reply."""

    key_expr = f"{CAR}/pilot/route"

    def __init__(self, data: bytes):
        self.payload, self.encoding, self.replies = zenoh.ZBytes(data), None, []

    def reply(self, key, payload, encoding=None) -> None:
        data = bytes(payload)
        self.replies.append(json.loads(data) if is_json_text(data) else msgpack.unpackb(data))


class FakeHealth:
    def __init__(self):
        self.errors: dict[str, int] = {}

    def error(self, name: str, n: int = 1) -> None:
        self.errors[name] = self.errors.get(name, 0) + n


def test_a_full_inbox_answers_busy_at_once(caplog):
    """The reader not started: the first `capacity` wait, the next is answered at once."""
    health, stopping = FakeHealth(), threading.Event()
    inbox = Inbox(Pilot(), logging.getLogger("viena.pilot"), health, stopping, capacity=3)
    on_query = inbox.on_query("route", FakeQuery.key_expr, "usage")
    queries = [FakeQuery(ROUTE) for _ in range(5)]
    for query in queries:
        on_query(query)
    assert [len(q.replies) for q in queries] == [0, 0, 0, 1, 1]
    assert queries[3].replies[0] == {"status": "rejected",
                                     "reason": "busy: 3 requests wait to be read; send it again later"}
    assert health.errors == {"route_busy": 2}
    inbox.start()                             # the waiting ones are read, in order
    taken: list = []
    assert wait_until(lambda: taken.extend(inbox.take()) or len(taken) == 3, 5.0)
    assert [r.number for r in taken] == [1, 2, 3] and all(r.kind == "route" and len(r.value) == 2 for r in taken)
    assert all(q.replies == [] for q in queries[:3])          # the control thread answers them
    stopping.set()
    inbox.join(1.0)


class FakeSample:
    """What Inbox needs of a zenoh.Sample: its payload and encoding."""

    def __init__(self, data: bytes):
        self.payload, self.encoding = zenoh.ZBytes(data), None


def test_a_flood_of_puts_leaves_room_for_queries():
    """CI: a query waited more than 5 s behind 32 large routes put by a flooder. Puts hold
    at most `puts_waiting` places; the rest are dropped and counted, queries still queue."""
    health, stopping = FakeHealth(), threading.Event()
    inbox = Inbox(Pilot(), logging.getLogger("viena.pilot"), health, stopping, capacity=8, puts_waiting=2)
    on_put, on_query = inbox.on_put("route"), inbox.on_query("route", FakeQuery.key_expr, "usage")
    for _ in range(10):
        on_put(FakeSample(ROUTE))
    assert health.errors == {"route_busy": 8}
    queries = [FakeQuery(ROUTE) for _ in range(6)]
    for query in queries:
        on_query(query)
    assert all(q.replies == [] for q in queries)          # all six queued behind the two puts
    inbox.start()
    taken: list = []
    assert wait_until(lambda: taken.extend(inbox.take()) or len(taken) == 8, 5.0)
    assert [r.query is None for r in taken] == [True, True] + [False] * 6
    on_put(FakeSample(ROUTE))                             # read: the puts' places are free again
    assert wait_until(lambda: taken.extend(inbox.take()) or len(taken) == 9, 5.0)
    assert health.errors == {"route_busy": 8}
    stopping.set()
    inbox.join(1.0)


LEAVES = st.none() | st.booleans() | st.integers(-2**63, 2**63 - 1) | st.floats() | st.text(max_size=5)
KEYS = st.sampled_from(["type", "points", "checkpoints", "lat", "lon", "coordinates", "geometry", "features",
                        "properties", "speeds_mps", "speed_mps", "APP_ROUTE_latitude", "APP_FINAL_COORDINATE", "x"])
JSON_VALUES = st.recursive(LEAVES | st.sampled_from(["Feature", "FeatureCollection", "LineString", "Point"]),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(KEYS, inner, max_size=5),
                           max_leaves=30)


@given(JSON_VALUES)
def test_any_json_or_msgpack_value_is_a_route_or_a_route_error(value):
    """Whatever shape comes: a Route, or one RouteError; never another exception."""
    for payload in (json.dumps(value).encode(), msgpack.packb(value)):
        try:
            parse_route(payload)
        except RouteError as exc:
            assert "\n" not in str(exc) and len(str(exc)) < 300
