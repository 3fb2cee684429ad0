"""An in-memory zenoh for the car in one process (issue 27).

`MemoryBus()` is one car's network; `bus.session(name)` is what `zenoh.open` gives a
program: publishers, subscribers, queryables, `get` and liveliness, on the same keys with
the same encoded payloads. A service does not know which it runs on. Real zenoh cannot
serve a virtual clock (its `get` waits inside Rust, on the wall clock), so every wait and
every thread here goes through `viena.common.clock`: the wall clock on ordinary threads,
the lockstep runner's virtual one on its threads. Create a session on the clock it will
run on (its callback threads start on the clock of the thread that declares them).

What it copies of zenoh-python 1.x (measured against eclipse-zenoh 1.10 in one process):

- Each declared callback (subscriber or queryable) is called on a thread of its own, in the
  order its samples or queries came; never in the putter's or getter's thread, so a callback
  may take the lock its putter holds. Undeclaring stops new deliveries; those queued already
  are still made, as zenoh's callback threads drain theirs. (`MemoryBus(one_thread_per_session
  =True)` calls all of a session's callbacks on one thread instead, in the order they were sent.)
- Keys are zenoh's (`zenoh.KeyExpr`: `*`, `**`, a bad key raises `zenoh.ZError`). A put
  gives every matching subscriber, its own session's too, a copy of the bytes.
- `get` reaches every matching queryable in the order they were declared (QueryTarget.ALL;
  BEST_MATCHING is the same while no queryable is `complete`). Iterating its answer yields
  the replies as they come and ends once every query was finalized, or with zenoh's
  `Timeout` error reply at the timeout. A query is finalized when the last reference to it
  goes (`__del__`: CPython frees it at once, as zenoh-python drops its Rust query), at
  `query.drop()`, or at the end of `with query:`. Replying to a dropped query raises; a
  reply after the timeout is lost silently; a reply on a key that does not intersect the
  query's raises. Consolidation NONE gives every reply; AUTO and LATEST the last one per
  key, once the query ended.
- Liveliness: `get` answers at once, one reply per alive token that matches; a liveliness
  subscriber hears PUT when a token appears and DELETE when it goes (`history=True`: the
  alive ones first). Tokens go with `undeclare`, with the session, and (as zenoh's) when the
  program lets go of its token object.
- `close()`: everything the session declared is undeclared, queries it holds are finalized
  (their getters stop waiting), and puts, gets and declarations raise `zenoh.ZError("session
  closed")`; undeclaring after it does nothing; `zid()` still answers. `kill()` is the program
  dying: the same, and not one more of its callbacks runs. `MemoryBus.close()` closes them all.

Left out: anything viena does not use raises NotImplementedError naming it (attachments,
timestamps, selector parameters, FIFO channels, complete queryables, MONOTONIC
consolidation, ...). QoS options (congestion control, priority, express, reliability) are
accepted and mean nothing: memory never drops and keeps order. zenoh's RingChannel does not
say its capacity, so every ring holds `ring_capacity` samples (1, as the services ask).

`latency_s`: every delivery (sample, query, reply) happens that long after it was sent.
"""
from __future__ import annotations

import functools
import itertools
import logging
import threading
import traceback
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple

import zenoh

from viena.common import clock

log = logging.getLogger(__name__)

#: zenoh's default query timeout (its config's `queries_default_timeout`)
DEFAULT_QUERY_TIMEOUT_S = 10.0
#: options that tune a network's delivery: in memory nothing is dropped or reordered
_QOS = frozenset({"congestion_control", "priority", "express", "reliability"})
_CLOSED = "session closed"
_PUT = zenoh.SampleKind.PUT


def _refuse_options(what: str, options: dict[str, Any]) -> None:
    """NotImplementedError for an option the bus does not have (QoS ones are accepted)."""
    for name, value in options.items():
        if value is not None and name not in _QOS:
            raise NotImplementedError(f"{what}({name}=...): not in the memory bus (viena does not use it)")


@functools.lru_cache(maxsize=4096)
def _key_expr(key: str) -> zenoh.KeyExpr:
    return zenoh.KeyExpr(key)


def _key(key_expr: Any) -> str:
    """A key expression as text, checked by zenoh (ZError if it is not one)."""
    return str(_key_expr(str(key_expr)))


@functools.lru_cache(maxsize=16384)
def _intersects(a: str, b: str) -> bool:
    return _key_expr(a).intersects(_key_expr(b))


@functools.lru_cache(maxsize=256)
def _named_encoding(name: str) -> zenoh.Encoding:
    return zenoh.Encoding(name)


def _encoding(encoding: Any, default: zenoh.Encoding = zenoh.Encoding.ZENOH_BYTES) -> zenoh.Encoding:
    if encoding is None:
        return default
    return encoding if isinstance(encoding, zenoh.Encoding) else _named_encoding(str(encoding))


def _due(latency_s: float) -> float:
    """When something sent now is delivered: 0.0 (at once) without latency, so a query
    finalized on any thread reads no clock."""
    return clock.monotonic() + latency_s if latency_s else 0.0


def _wait_until(due: float) -> None:
    if due:
        wait = due - clock.monotonic()
        if wait > 0:
            clock.sleep(wait)


# -- what zenoh hands out ------------------------------------------------------------------------
@dataclass(frozen=True)
class MemoryId:
    """Stands for zenoh.ZenohId: str() is the session's name and generation, "mem-steering-2"."""

    text: str

    def __str__(self) -> str:
        return self.text


@dataclass(frozen=True)
class EntityId:
    """Stands for zenoh.EntityGlobalId (a reply's `replier_id`)."""

    zid: MemoryId
    eid: int


class Sample(NamedTuple):
    """zenoh.Sample's read-only attributes. A NamedTuple: one is made per put, and a frozen
    dataclass takes three times as long to build (1.1 us against 0.35)."""

    key_expr: zenoh.KeyExpr
    payload: zenoh.ZBytes
    encoding: zenoh.Encoding
    kind: zenoh.SampleKind
    timestamp: None = None
    attachment: None = None


@dataclass(frozen=True)
class ReplyError:
    payload: zenoh.ZBytes
    encoding: zenoh.Encoding


@dataclass(frozen=True)
class Reply:
    ok: Sample | None
    err: ReplyError | None = None
    replier_id: EntityId | None = None

    @property
    def result(self) -> Sample | ReplyError:
        return self.ok if self.ok is not None else self.err  # type: ignore[return-value]  # one is always set


TIMEOUT = Reply(None, ReplyError(zenoh.ZBytes(b"Timeout"), zenoh.Encoding.ZENOH_STRING))


# -- threads that call callbacks -----------------------------------------------------------------
class _CallbackThread:
    """Calls what was posted to it, in order, on a thread of its own (zenoh-python gives one
    to each declared callback). `stop()` lets it finish what is queued, then end."""

    def __init__(self, name: str, session: MemorySession):
        self._jobs = clock.Queue()
        self._session = session
        clock.Thread(self._run, name=name, daemon=True).start()

    def post(self, due: float, call: Callable[[Any], None], item: Any) -> None:
        self._jobs.put((due, call, item))

    def stop(self) -> None:
        self._jobs.put(None)

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            due, call, item = job
            del job
            if due:
                _wait_until(due)
            if not self._session.killed:
                try:
                    call(item)
                except Exception:   # as zenoh-python: said, and the thread goes on (as text: a kept
                    log.error("callback error\n%s", traceback.format_exc())   # traceback keeps a query)
            del item            # a query is finalized when its last reference goes: not at the next job


# -- what a session declares ---------------------------------------------------------------------
class _Declared:
    """A subscriber, queryable, publisher or liveliness token of one session."""

    kind = "entity"

    def __init__(self, session: MemorySession, key: str):
        self._session, self.key = session, key
        self.eid = next(session._eids)
        self.undeclared = False

    @property
    def key_expr(self) -> zenoh.KeyExpr:
        return _key_expr(self.key)

    def undeclare(self) -> None:
        if self._session.is_closed():
            return
        if self.undeclared:
            raise zenoh.ZError(f"Undeclared {self.kind}")
        self._session._forget(self)

    def _vanish(self) -> None:
        """Leave the bus (at undeclare, or when the session goes)."""
        self.undeclared = True


class _Receiver(_Declared):
    """Something the bus delivers to through a callback thread."""

    table = ""

    def __init__(self, session: MemorySession, key: str, deliver: Callable[[Any], None]):
        super().__init__(session, key)
        self._deliver = deliver
        self._thread = session._callback_thread(f"{session.zid()}-{self.kind}-{self.eid}")

    def post(self, item: Any) -> None:
        if not self.undeclared:
            latency_s = self._session._bus.latency_s
            self._thread.post(_due(latency_s) if latency_s else 0.0, self._deliver, item)

    def _vanish(self) -> None:
        super()._vanish()
        self._session._bus._remove(self.table, self)
        if self._thread is not self._session._shared_thread:
            self._thread.stop()


class MemorySubscriber(_Receiver):
    """A subscriber with a callback, or with a zenoh.handlers.RingChannel (`try_recv`, `recv`)."""

    kind, table = "subscriber", "subscribers"

    def __init__(self, session: MemorySession, key: str, handler: Any):
        self._ring = None
        if isinstance(handler, zenoh.handlers.RingChannel):
            self._ring = clock.Queue(maxsize=session._bus.ring_capacity)
            deliver = self._keep
        elif callable(handler):
            deliver = handler
        else:
            raise NotImplementedError(f"a subscriber's handler {handler!r}: the memory bus takes a callback "
                                      f"or a RingChannel")
        super().__init__(session, key, deliver)

    def _keep(self, sample: Sample) -> None:
        """The newest `ring_capacity` samples (only this subscriber's thread adds)."""
        assert self._ring is not None
        while True:
            try:
                self._ring.put_nowait(sample)
                return
            except clock.Full:
                try:
                    self._ring.get_nowait()
                except clock.Empty:
                    pass

    def try_recv(self) -> Sample | None:
        ring = self._channel()
        try:
            return ring.get_nowait()
        except clock.Empty:
            return None

    def recv(self) -> Sample:
        return self._channel().get()

    def _channel(self) -> Any:
        if self._ring is None:
            raise zenoh.ZError("this subscriber has a callback, not a channel")
        if self.undeclared:
            raise zenoh.ZError("The ringbuffer has been deleted.")
        return self._ring


class _LivelinessSubscriber(MemorySubscriber):
    table = "watchers"


class MemoryQueryable(_Receiver):
    kind, table = "queryable", "queryables"


class MemoryPublisher(_Declared):
    kind = "publisher"

    def __init__(self, session: MemorySession, key: str, encoding: zenoh.Encoding):
        super().__init__(session, key)
        self.encoding = encoding

    def put(self, payload: Any, *, encoding: Any = None, **options: Any) -> None:
        if options:
            _refuse_options("Publisher.put", options)
        if self.undeclared:
            self._session._check()
            raise zenoh.ZError("Undeclared publisher")
        self._session._put(self.key, payload, self.encoding if encoding is None else _encoding(encoding))


class _Alive(_Declared):
    """A liveliness token as the bus keeps it (the program's MemoryToken holds it)."""

    kind = "LivelinessToken"

    def _vanish(self) -> None:
        super()._vanish()
        self._session._bus._remove("tokens", self)
        self._session._bus._tell_watchers(self.key, zenoh.SampleKind.DELETE)


class MemoryToken:
    """A liveliness token: alive until undeclared, its session closes, or (as zenoh's) it is
    garbage: a program that forgets its token is not seen any more."""

    def __init__(self, alive: _Alive):
        self._alive = alive

    @property
    def key_expr(self) -> zenoh.KeyExpr:
        return self._alive.key_expr

    def undeclare(self) -> None:
        self._alive.undeclare()

    def __del__(self) -> None:
        alive = self._alive
        if not alive.undeclared and not alive._session.is_closed():
            alive._session._forget(alive)


# -- queries -------------------------------------------------------------------------------------
class Replies:
    """What `get` returns (zenoh's Handler[Reply]): iterating waits for the replies, in the
    order they come, until every query was finalized or the timeout."""

    def __init__(self, timeout_s: float, latest: bool):
        self._inbox = clock.Queue()
        self._open: set[int] = set()      # the queries not finalized yet, by number
        self._deadline = clock.monotonic() + timeout_s
        self._replies = self._latest() if latest else self._arrivals()

    def __iter__(self) -> Iterator[Reply]:
        return self

    def __next__(self) -> Reply:
        return next(self._replies)

    def post(self, number: int, reply: Reply | None, latency_s: float) -> None:
        """A reply to query `number`, or None: that query was finalized."""
        self._inbox.put((_due(latency_s), number, reply))

    def _arrivals(self) -> Iterator[Reply]:
        while self._open:
            try:
                due, number, reply = self._inbox.get(timeout=max(0.0, self._deadline - clock.monotonic()))
            except clock.Empty:
                break
            if due > self._deadline:      # it would come after the timeout
                break
            _wait_until(due)
            if reply is None:
                self._open.discard(number)
            else:
                yield reply
        if self._open:
            self._open.clear()
            yield TIMEOUT

    def _latest(self) -> Iterator[Reply]:
        """zenoh's LATEST consolidation: the last reply per key, once the query ended (errors at once)."""
        latest: dict[str, Reply] = {}
        timed_out = False
        for reply in self._arrivals():
            if reply is TIMEOUT:
                timed_out = True
            elif reply.ok is None:
                yield reply
            else:
                latest[str(reply.ok.key_expr)] = reply
        yield from latest.values()
        if timed_out:
            yield TIMEOUT


class MemoryQuery:
    """What a queryable's callback gets. Its getter hears the end of it when it is finalized:
    when the last reference to it goes, or at `drop()`, or at the end of `with query:`."""

    def __init__(self, replies: Replies, number: int, key: str, payload: zenoh.ZBytes | None,
                 encoding: zenoh.Encoding | None, queryable: MemoryQueryable):
        self._replies, self._number, self._key = replies, number, key
        self.payload, self.encoding = payload, encoding
        self.attachment = None
        self._replier = queryable._session
        self._replier_id = EntityId(self._replier.zid(), queryable.eid)
        self._done = False
        self._replier._held[number] = self

    @property
    def key_expr(self) -> zenoh.KeyExpr:
        """The getter's key expression (a wildcard if it asked with one), not the queryable's."""
        return _key_expr(self._key)

    @property
    def selector(self) -> zenoh.Selector:
        return zenoh.Selector(self._key)

    def reply(self, key_expr: Any, payload: Any, *, encoding: Any = None, **options: Any) -> None:
        _refuse_options("Query.reply", options)
        key = _key(key_expr)
        self._check()
        if not _intersects(key, self._key):
            raise zenoh.ZError(f"Attempted to reply on `{key}`, which does not intersect with query "
                               f"`{self._key}`, despite query only allowing replies on matching key expressions")
        self._send(Reply(Sample(_key_expr(key), zenoh.ZBytes(payload), _encoding(encoding), zenoh.SampleKind.PUT),
                         replier_id=self._replier_id))

    def reply_err(self, payload: Any, *, encoding: Any = None) -> None:
        self._check()
        self._send(Reply(None, ReplyError(zenoh.ZBytes(payload), _encoding(encoding)), self._replier_id))

    def drop(self) -> None:
        self._finalize()

    def __enter__(self) -> MemoryQuery:
        return self

    def __exit__(self, *_exc: Any) -> None:
        self._finalize()

    def __del__(self) -> None:
        self._finalize()

    def __str__(self) -> str:
        return self._key

    def _check(self) -> None:
        if self._replier.is_closed():
            raise zenoh.ZError(_CLOSED)
        if self._done:
            raise zenoh.ZError("Dropped query")

    def _send(self, reply: Reply) -> None:
        self._replies.post(self._number, reply, self._replier._bus.latency_s)

    def _finalize(self) -> None:
        if not self._done:
            self._done = True
            self._replier._held.pop(self._number, None)
            self._replies.post(self._number, None, self._replier._bus.latency_s)


# -- the session ---------------------------------------------------------------------------------
class Liveliness:
    """`session.liveliness()`."""

    def __init__(self, session: MemorySession):
        self._session = session

    def declare_token(self, key_expr: Any) -> MemoryToken:
        session = self._session
        session._check()
        alive = _Alive(session, _key(key_expr))
        session._declare(alive, "tokens")
        session._bus._tell_watchers(alive.key, zenoh.SampleKind.PUT)
        return MemoryToken(alive)

    def get(self, key_expr: Any, handler: Any = None, *, timeout: float | None = None,
            **options: Any) -> Iterator[Reply]:
        """One reply per alive token that matches, at once (`timeout` is not needed)."""
        _refuse_options("Liveliness.get", {"handler": handler, **options})
        self._session._check()
        return iter([Reply(_token_sample(token.key, zenoh.SampleKind.PUT))
                     for token in self._session._bus._matching("tokens", _key(key_expr))])

    def declare_subscriber(self, key_expr: Any, handler: Any = None, *, history: bool | None = None
                           ) -> MemorySubscriber:
        session = self._session
        session._check()
        watcher = _LivelinessSubscriber(session, _key(key_expr), handler)
        session._declare(watcher, "watchers")
        if history:
            for token in session._bus._matching("tokens", watcher.key):
                watcher.post(_token_sample(token.key, zenoh.SampleKind.PUT))
        return watcher


def _token_sample(key: str, kind: zenoh.SampleKind) -> Sample:
    return Sample(_key_expr(key), zenoh.ZBytes(b""), zenoh.Encoding.ZENOH_BYTES, kind)


class MemorySession:
    """A program's zenoh.Session on a MemoryBus. See the module docstring."""

    def __init__(self, bus: MemoryBus, zid: MemoryId):
        self._bus, self._zid = bus, zid
        self._closed = self.killed = False
        self._eids = itertools.count(1)
        self._declared: list[_Declared] = []
        self._held: weakref.WeakValueDictionary[int, MemoryQuery] = weakref.WeakValueDictionary()
        self._shared_thread: _CallbackThread | None = None

    def zid(self) -> MemoryId:
        return self._zid

    def is_closed(self) -> bool:
        return self._closed

    def declare_publisher(self, key_expr: Any, *, encoding: Any = None, **options: Any) -> MemoryPublisher:
        _refuse_options("declare_publisher", options)
        self._check()
        publisher = MemoryPublisher(self, _key(key_expr), _encoding(encoding))
        self._declared.append(publisher)
        return publisher

    def put(self, key_expr: Any, payload: Any, *, encoding: Any = None, **options: Any) -> None:
        _refuse_options("put", options)
        self._put(_key(key_expr), payload, _encoding(encoding))

    def declare_subscriber(self, key_expr: Any, handler: Any = None, **options: Any) -> MemorySubscriber:
        _refuse_options("declare_subscriber", options)
        self._check()
        subscriber = MemorySubscriber(self, _key(key_expr), handler)
        self._declare(subscriber, "subscribers")
        return subscriber

    def declare_queryable(self, key_expr: Any, handler: Any = None, **options: Any) -> MemoryQueryable:
        _refuse_options("declare_queryable", options)
        self._check()
        if not callable(handler):
            raise NotImplementedError(f"a queryable's handler {handler!r}: the memory bus takes a callback")
        queryable = MemoryQueryable(self, _key(key_expr), handler)
        self._declare(queryable, "queryables")
        return queryable

    def get(self, selector: Any, handler: Any = None, *, target: zenoh.QueryTarget | None = None,
            consolidation: Any = None, timeout: float | None = None, payload: Any = None,
            encoding: Any = None, **options: Any) -> Replies:
        """Asks every matching queryable; the answer yields their replies as they come."""
        _refuse_options("get", {"handler": handler, **options})
        self._check()
        if target not in (None, zenoh.QueryTarget.BEST_MATCHING, zenoh.QueryTarget.ALL):
            raise NotImplementedError(f"get(target={target}): the memory bus has no complete queryables")
        modes = zenoh.ConsolidationMode
        if consolidation not in (None, modes.AUTO, modes.LATEST, modes.NONE):
            raise NotImplementedError(f"get(consolidation={consolidation}): the memory bus has NONE, AUTO and LATEST")
        parsed = zenoh.Selector(str(selector))
        if str(parsed.parameters):
            raise NotImplementedError(f"get({selector!r}): the memory bus takes no selector parameters")
        key = _key(parsed.key_expr)
        if payload is not None or encoding is not None:     # as zenoh: both, or neither
            asked, asked_as = zenoh.ZBytes(b"" if payload is None else payload), _encoding(encoding)
        else:
            asked, asked_as = None, None
        replies = Replies(DEFAULT_QUERY_TIMEOUT_S if timeout is None else timeout,
                          latest=consolidation != modes.NONE)
        for queryable in self._bus._matching("queryables", key):
            number = next(self._bus._numbers)
            replies._open.add(number)
            queryable.post(MemoryQuery(replies, number, key, asked, asked_as, queryable))
        return replies

    def liveliness(self) -> Liveliness:
        return Liveliness(self)

    def close(self) -> None:
        """Undeclare everything, finalize the queries held, refuse anything more."""
        if self._closed:
            return
        self._closed = True
        for declared in reversed(self._declared):
            declared._vanish()
        self._declared.clear()
        if self._shared_thread is not None:
            self._shared_thread.stop()
        for query in list(self._held.values()):
            query._finalize()

    def kill(self) -> None:
        """The program died: as close(), and none of its callbacks runs again, not even
        those already queued (for the lockstep runner; zenoh has no such call)."""
        self.killed = True
        self.close()

    def __enter__(self) -> MemorySession:
        return self

    def __exit__(self, *_exc: Any) -> None:
        self.close()

    # -- for the bus's classes -----------------------------------------------------------------
    def _check(self) -> None:
        if self._closed:
            raise zenoh.ZError(_CLOSED)

    def _put(self, key: str, payload: Any, encoding: zenoh.Encoding) -> None:
        if self._closed:
            raise zenoh.ZError(_CLOSED)
        sample = Sample(_key_expr(key), zenoh.ZBytes(payload), encoding, _PUT)   # a copy of the bytes
        for subscriber in self._bus._matching("subscribers", key):
            subscriber.post(sample)

    def _callback_thread(self, name: str) -> _CallbackThread:
        if not self._bus.one_thread_per_session:
            return _CallbackThread(name, self)
        if self._shared_thread is None:
            self._shared_thread = _CallbackThread(f"{self._zid}-callbacks", self)
        return self._shared_thread

    def _declare(self, declared: _Declared, table: str) -> None:
        self._declared.append(declared)
        self._bus._add(table, declared)

    def _forget(self, declared: _Declared) -> None:
        self._declared.remove(declared)
        declared._vanish()


class MemoryBus:
    """One car's network: the sessions of its programs and what they declared."""

    def __init__(self, latency_s: float = 0.0, ring_capacity: int = 1, one_thread_per_session: bool = False):
        self.latency_s = latency_s
        self.ring_capacity = ring_capacity
        self.one_thread_per_session = one_thread_per_session
        self._lock = threading.Lock()     # held only to swap the tables: never across a wait
        # what is declared, in the order it was (so deliveries are in that order), and the
        # matches found so far for each (table, key); both replaced, never changed, at a change
        self._routes: tuple[dict[str, tuple], dict[tuple[str, str], tuple]] = (
            {"subscribers": (), "queryables": (), "tokens": (), "watchers": ()}, {})
        self._generations: dict[str, int] = {}
        self._sessions: list[MemorySession] = []
        self._numbers = itertools.count(1)

    def session(self, name: str) -> MemorySession:
        """A new session for program `name`; its id says which start of it this is ("mem-gnss-2")."""
        with self._lock:
            generation = self._generations[name] = self._generations.get(name, 0) + 1
            session = MemorySession(self, MemoryId(f"mem-{name}-{generation}"))
            self._sessions.append(session)
        return session

    def close(self) -> None:
        """Close every session (the end of a run: their callback threads end)."""
        for session in self._sessions:
            session.close()

    def _matching(self, table: str, key: str) -> tuple:
        tables, found = self._routes
        matches = found.get((table, key))
        if matches is None:
            matches = found[(table, key)] = tuple(d for d in tables[table] if _intersects(d.key, key))
        return matches

    def _add(self, table: str, declared: _Declared) -> None:
        with self._lock:
            tables = self._routes[0]
            self._routes = ({**tables, table: (*tables[table], declared)}, {})

    def _remove(self, table: str, declared: _Declared) -> None:
        with self._lock:
            tables = self._routes[0]
            self._routes = ({**tables, table: tuple(d for d in tables[table] if d is not declared)}, {})

    def _tell_watchers(self, key: str, kind: zenoh.SampleKind) -> None:
        for watcher in self._matching("watchers", key):
            watcher.post(_token_sample(key, kind))
