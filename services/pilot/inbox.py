"""What comes on pilot/route and pilot/cmd, read off the control thread.

The zenoh callbacks only size a payload up and queue it: one larger than its kind's limit,
or one more while `capacity` wait already, is answered at once and never queued. Puts
(which nobody waits on) may hold only PUTS_WAITING of those places: a flood of puts is
dropped and counted at the door, so a query waits behind a few puts at most, never behind
a full queue of them. One
reader thread takes the rest in the order they came, reads each (model/route.py bounds a
route's size and depth, parse_payload a command's), answers every refusal itself, and
hands the control thread only what it has to decide: a Route read and checked (its
"accepted" answer already encoded) or a command word. A query without payload is answered
by the reader, from the route held. So a flood of malformed or large routes costs the
reader's time and never the control step's; and while following (with every earlier
request decided) a route is refused before it is read, since nothing would take it.

Every refusal: the reason to whoever asked, a counter in health (`route_rejected`,
`cmd_busy`, ...), a log line at most every 10 s per kind (Throttled), never a traceback.
"""
from __future__ import annotations

import itertools
import queue
import threading
from dataclasses import dataclass
from typing import Any

import zenoh

from viena.common import clock
from viena.common.errors import PayloadError
from viena.common.log import Throttled
from viena.common.payload import MAX_COMMAND_BYTES, parse_payload, reply_bytes
from viena.common.service import query_payload, reply_to
from viena.services.pilot.model.pilot import IDLE, Pilot
from viena.services.pilot.model.route import MAX_ROUTE_BYTES, RouteError, parse_route

ROUTE, CMD = "route", "cmd"
ACCEPTED, REJECTED = "accepted", "rejected"
MAX_BYTES = {ROUTE: MAX_ROUTE_BYTES, CMD: MAX_COMMAND_BYTES}
#: requests waiting to be read, and read ones waiting for the control thread (32 routes of
#: 256 KiB: 8 MB, read in about a second)
CAPACITY = 32
#: of those, the most that may be puts (a query waits behind these at most, plus other queries)
PUTS_WAITING = 4
#: the most requests the control thread decides in one tick
PER_TICK = 8


@dataclass
class Request:
    """A route read or a command word, for the control thread to decide, and whom to answer."""

    kind: str                        # ROUTE or CMD
    value: Any                       # the Route, or "start" / "stop"
    query: Any                       # the zenoh.Query to answer; None for a put
    like: tuple[str | None, bytes]   # the question's encoding and first bytes: the answer's follow
    number: int                      # in the order of arrival (estops are numbered too)
    accepted: tuple[bytes, str] | None = None   # a route's answer if it is taken, encoded

    def answer(self, answer: dict) -> None:
        if self.query is not None:
            reply_to(self.query, answer, *self.like)

    def answer_accepted(self) -> None:
        """The answer encoded by the reader (an `accepted` with a 5,000-point route takes
        about 10 ms to encode: not the control thread's time)."""
        if self.query is not None and self.accepted is not None:
            payload, encoding = self.accepted
            self.query.reply(self.query.key_expr, payload, encoding=zenoh.Encoding(encoding))


class Inbox:
    """See the module docstring. The control thread calls `take` each tick, and `decided`
    after each request taken."""

    def __init__(self, pilot: Pilot, log, health, stopping: Any, capacity: int = CAPACITY,
                 puts_waiting: int = PUTS_WAITING):
        self._pilot, self._health, self._stopping = pilot, health, stopping
        self._arrived = clock.Queue(maxsize=capacity)
        # only ever acquired without blocking: a count, never a wait
        self._put_places = threading.BoundedSemaphore(min(puts_waiting, capacity))  # noqa: TID251
        self._read = clock.Queue(maxsize=capacity)
        self._numbers = itertools.count(1)
        self._handed = self._decided = 0            # each written by one thread only
        self._refusals = Throttled(log, "refused")
        self._log = log
        self._thread = clock.Thread(target=self._run, name="pilot-inbox", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def join(self, timeout_s: float) -> None:
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def number(self) -> int:
        """A number for an event outside the inbox (an estop): those of requests that came
        before it are lower."""
        return next(self._numbers)

    # -- zenoh callbacks: never block, never read --------------------------------------------
    def on_query(self, kind: str, own_key: str, usage: str):
        def on_query(query: zenoh.Query) -> None:
            data, encoding = query_payload(query)
            if str(query.key_expr) != own_key:            # a wildcard query: never a command
                reply_to(query, {"status": "description", "key": own_key, "usage": usage},
                         encoding, data, own_key)
                return
            self._arrive(kind, data, encoding, query)
        return on_query

    def on_put(self, kind: str):
        def on_put(sample: zenoh.Sample) -> None:
            self._arrive(kind, sample.payload.to_bytes(), str(sample.encoding), None)
        return on_put

    def _arrive(self, kind: str, data: bytes, encoding: str | None, query) -> None:
        number = self.number()
        like = (encoding, data[:64])
        if len(data) > MAX_BYTES[kind]:
            self._refuse(kind, query, like, f"{kind} of {len(data)} bytes: at most {MAX_BYTES[kind]} are read")
            return
        if query is None and not self._put_places.acquire(blocking=False):
            self._refuse(kind, query, like, "busy: puts wait to be read; send it again later", "busy")
            return
        try:
            self._arrived.put_nowait((kind, data, encoding, query, number))
        except queue.Full:
            if query is None:
                self._put_places.release()
            self._refuse(kind, query, like, f"busy: {self._arrived.maxsize} requests wait to be read; "
                                            f"send it again later", "busy")

    # -- the reader thread --------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stopping.is_set():
            try:
                arrived = self._arrived.get(timeout=0.1)
            except queue.Empty:
                continue
            if arrived[3] is None:                      # a put's place is free again
                self._put_places.release()
            self._serve(*arrived)
            del arrived        # a query's answers end when the last reference to it goes

    def _serve(self, kind: str, data: bytes, encoding: str | None, query, number: int) -> None:
        like = (encoding, data[:64])
        try:
            request = self._request(kind, data, encoding, query, like, number)
        except (RouteError, PayloadError) as exc:
            self._refuse(kind, query, like, str(exc))
            return
        except Exception as exc:                      # noqa: BLE001 - a bug: refused, and the reader goes on
            self._health.error("reader_internal")
            if self._refusals.log("internal error", f"reading a {kind}: {type(exc).__name__}: {exc}"[:300]):
                self._log.debug("reading a %s failed", kind, exc_info=True)
            self._refuse(kind, query, like, f"internal error reading the {kind} (see the pilot's log)")
            return
        if request is not None:
            self._hand_over(request)

    def _request(self, kind: str, data: bytes, encoding: str | None, query, like, number: int) -> Request | None:
        if kind == CMD:
            return Request(CMD, command_of(data, encoding), query, like, number)
        if not data:                                  # which route is held: the reader answers
            if query is not None:
                reply_to(query, self._held(), *like)
            return None
        # while following nothing would take it; unless a request before it (a stop) is undecided
        why = self._pilot.route_problem() if self._handed == self._decided else None
        if why is not None:
            raise RouteError(why)
        route = parse_route(data, encoding)
        accepted = None
        if query is not None:                         # set_route leaves the pilot idle
            accepted = reply_bytes({"status": ACCEPTED, "route": route.to_geojson(), "mode": IDLE}, *like)
        return Request(ROUTE, route, query, like, number, accepted)

    def _held(self) -> dict:
        route, mode = self._pilot.route, self._pilot.mode
        if route is None:
            return {"status": REJECTED, "reason": "no route yet"}
        return {"status": ACCEPTED, "route": route.to_geojson(), "mode": mode}

    def _hand_over(self, request: Request) -> None:
        self._handed += 1
        while not self._stopping.is_set():
            try:
                self._read.put(request, timeout=0.1)
                return
            except queue.Full:
                continue

    # -- the control thread -------------------------------------------------------------------
    def take(self, limit: int = PER_TICK) -> list[Request]:
        """Requests read, in order, at most `limit` (the rest wait for the next tick)."""
        taken: list[Request] = []
        while len(taken) < limit:
            try:
                taken.append(self._read.get_nowait())
            except queue.Empty:
                break
        return taken

    def decided(self) -> None:
        self._decided += 1

    def refuse(self, request: Request, reason: str) -> None:
        """A request the control thread refuses: answered, counted and logged as the reader's are."""
        self._refuse(request.kind, request.query, request.like, reason)

    def _refuse(self, kind: str, query, like, reason: str, why: str = "rejected") -> None:
        answer: dict = {"status": REJECTED, "reason": reason}
        if kind == CMD:
            answer["mode"] = self._pilot.mode
        self._health.error(f"{kind}_{why}")
        self._refusals.log(kind if why == "rejected" else f"{kind} {why}", reason)
        if query is not None:
            reply_to(query, answer, *like)


def command_of(data: bytes, encoding: str | None = None) -> str:
    """`start` or `stop` from {"cmd": ..} (JSON or msgpack) or the bare word; PayloadError else."""
    if len(data) <= 16:
        word = bytes(data).strip().strip(b'"').decode("utf-8", "replace").lower()
        if word in ("start", "stop"):
            return word
    obj = parse_payload(data, encoding)
    cmd = obj.get("cmd")
    if set(obj) != {"cmd"} or cmd not in ("start", "stop"):
        raise PayloadError('expected {"cmd": "start"} or {"cmd": "stop"}')
    return cmd
