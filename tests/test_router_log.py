"""How `viena router` reads zenoh's own log (viena/router_log.py): lines as zenoh 1.10 writes
them (ANSI colours and all), and what the router's log says of them."""
from __future__ import annotations

import logging

import pytest

from viena.router_log import ZenohLog

OBSERVER = "ba4c5c85e9425aa92b90eebe60d0ebb5"
STEERING = "67a14a22d6f2a85a7795f0ae58056354"
SUBJECT = "Interface(lo)+CertCommonName({cn})+Transport(Tls)+{zid}"
ACL = "zenoh::net::routing::interceptor::access_control"


def line(message: str, target: str = ACL, level: str = "TRACE", thread: str = "09") -> bytes:
    """One line of zenoh's log, coloured as its tracing subscriber writes it to a pipe."""
    return (f"\x1b[2m2026-11-27T21:52:13.353058Z\x1b[0m \x1b[35m{level}\x1b[0m  rx-0 ThreadId({thread}) "
            f"\x1b[2m{target}\x1b[0m\x1b[2m:\x1b[0m {message}").encode()


def decision(zid: str, cn: str, verdict: str, action: str, key: str) -> str:
    return f"{zid} on {SUBJECT.format(cn=cn, zid=zid)} is {verdict} to {action} on {key}"


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def reader(caplog):
    caplog.set_level(5)
    clock = Clock()
    reader = ZenohLog(clock=clock)
    reader.clock = clock
    return reader


def said(caplog, logger: str = "viena.router") -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == logger]


def test_a_denied_message_is_logged_with_who_sent_it_and_its_key(reader, caplog):
    reader.feed(line(decision(OBSERVER, "observer.ce6fad60", "unauthorized", "Put (ingress)",
                              "viena/elettra/gnss/gnss0/fix")))
    assert said(caplog) == [f"denied: Put (ingress) from observer.ce6fad60 (zid {OBSERVER}) "
                            f"(viena/elettra/gnss/gnss0/fix)"]
    assert caplog.records[0].levelno == logging.WARNING


def test_a_flood_of_denials_is_one_line_per_ten_seconds_with_how_many_came(reader, caplog):
    denied = decision(OBSERVER, "observer.ce6fad60", "unauthorized", "Query (ingress)", "viena/elettra/steering/arm")
    cached = f"Using cached result: {OBSERVER} is unauthorized to Query (ingress) on viena/elettra/steering/arm"
    reader.feed(line(denied))
    for _ in range(1000):
        reader.feed(line(cached))
    reader.clock.now = 10.0
    reader.feed(line(cached))
    lines = said(caplog)
    assert len(lines) == 2
    assert lines[1].startswith("denied: Query (ingress) from observer.ce6fad60 (zid ")   # named by its id
    assert lines[1].endswith("[1000 more since it was last logged]")


def test_the_decisions_zenoh_caches_for_a_new_key_are_not_denials(reader, caplog):
    """When a key is first seen on a face, zenoh decides (and logs) every kind of message
    for it: the steering service declaring its queryable is 'unauthorized to Query' there,
    and did nothing wrong. A real denial on the same thread afterwards is one."""
    key = "viena/elettra/steering/arm"
    reader.feed(line(f"ACL (ingress): caching permissions for `{key}` ..."))
    for action in ("Query (ingress)", "Put (ingress)", "Declare Liveliness Subscriber (ingress)"):
        reader.feed(line(decision(STEERING, "steering.9e51", "unauthorized", action, key)))
    assert said(caplog) == []
    reader.feed(line(decision(OBSERVER, "observer.ce6f", "unauthorized", "Query (ingress)", key)))
    assert said(caplog) == [f"denied: Query (ingress) from observer.ce6f (zid {OBSERVER}) ({key})"]


def test_a_client_in_no_subject_is_named_once(reader, caplog):
    reader.names[OBSERVER] = "carol.12ab"
    reader.feed(line(f"{OBSERVER} did not match any configured ACL subject. Default permission `Deny` will be "
                     f"applied on all messages", level="INFO"))
    assert said(caplog) == [f"carol.12ab (zid {OBSERVER}) is in no access-control subject: everything it sends "
                            f"is denied"]


def test_a_message_cut_by_a_limit_names_the_client_from_the_digits_its_face_shows(reader, caplog):
    reader.names[OBSERVER] = "mallory.77aa"
    cut = ("Message dropped by the downsampling interceptor: Request(viena/elettra/steering/arm) "
           f"from:south:0:client/{OBSERVER[:8]}:1")
    for _ in range(3):
        reader.feed(line(cut, target="zenoh::net::routing::interceptor::downsampling"))
    assert said(caplog) == [f"cut by the router's limit: queries on viena/elettra/steering/arm from "
                            f"mallory.77aa (zid {OBSERVER})"]


def test_failed_tls_handshakes_are_counted_without_zenohs_misleading_hint(reader, caplog):
    for _ in range(5):
        reader.feed(line("tls handshake eof. Hint: increase the system open file limit.",
                         target="zenoh_link_tls::unicast", level="WARN", thread="06"))
    assert said(caplog) == ["TLS connection failed before any session: TLS handshakes failed (tls handshake eof)"]


def test_anything_else_zenoh_says_goes_to_the_log_as_it_is(reader, caplog):
    reader.feed(line("Unable to connect to any locator", target="zenoh::net::runtime", level="ERROR"))
    reader.feed(b"not a log line at all")
    assert said(caplog, "zenoh") == ["zenoh::net::runtime: Unable to connect to any locator",
                                     "not a log line at all"]
    assert [r.levelno for r in caplog.records] == [logging.ERROR, logging.INFO]
