"""The NTRIP client's state, viena.ntrip.state/1, on viena/<car>/ntrip/state (1 Hz and at
every change of state, reason or base station).

What a field engineer asks of a corrections link: which caster and mountpoint, is it
streaming, and if not why not and when the next attempt is; how much comes (bytes/s over
the last 10 s), which RTCM messages (and how many of each since start), from which base
station, and how old the last one is.
"""
from __future__ import annotations

from typing import NamedTuple

from viena.common.display import CORRECTIONS_STALE_S, Alert, fmt_age, fmt_unit, number
from viena.common.schema import F, Schema

#: connecting: an attempt is under way; streaming: the caster sends the mountpoint's data;
#: waiting: the last attempt failed or the stream ended, the next comes after the backoff;
#: refused: the caster answered no (credentials, mountpoint, not NTRIP): a person must look,
#: though the client keeps trying at the longest backoff; stopped: the process is stopping
STATES = ("connecting", "streaming", "waiting", "refused", "stopped")

STATE = Schema("viena.ntrip.state/1", {
    "t": F.time,
    "seq": F.int,
    "caster": F.str,                        # host:port
    "mountpoint": F.str,
    "version": F.enum("1.0", "2.0"),        # NTRIP version asked for
    "tls": F.bool,
    "format": F.str,                        # RTCMV3 (checked frames) or RAW
    "connected": F.bool,                    # the caster answered with the mountpoint's stream
    "state": F.enum(*STATES),
    "why": F.optional(F.str),               # why not streaming (or what is wrong while streaming)
    "next_attempt_s": F.optional(F.float),  # while waiting or refused: seconds to the next attempt
    "bytes_per_s": F.float,                 # corrections read, over the last 10 s
    "messages": F.map,                      # RTCM 3 message number (as text) -> frames since start
    "base_id": F.optional(F.str),           # reference station id (DF003) of the last frame naming one
    "last_message_age_s": F.optional(F.float),   # since the last frame (RAW: bytes) was read
    "attempts": F.int,                      # connection attempts since start
    "connects": F.int,                      # of which the caster streamed
    "gga_sent": F.int,                      # GGA sentences sent upstream since start
})


class NtripState(NamedTuple):
    """The client's state as a reader (the monitor, `viena doctor`) uses it."""

    caster: str
    mountpoint: str
    connected: bool
    state: str
    why: str | None
    next_attempt_s: float | None
    bytes_per_s: float
    messages: dict
    base_id: str | None
    last_message_age_s: float | None


_FIELDS = STATE.reader(*NtripState._fields)


def read_state(sample) -> NtripState:
    """The NtripState in a decoded sample; a FieldError names the field that is wrong."""
    return NtripState(*_FIELDS(sample))


def monitor_view(state: dict) -> dict[str, str]:
    """How the monitor shows the client's state (any map): a link that is not streaming
    asks to be noticed, with its reason."""
    what = str(state.get("state") or "-")
    why = state.get("why")
    if why:
        what += f" ({why})"
    wait = number(state.get("next_attempt_s"))
    if state.get("state") in ("waiting", "refused") and wait is not None:
        what += f", again in {wait:.0f} s"
    messages = state.get("messages")
    types = ",".join(sorted(messages, key=str)) if isinstance(messages, dict) and messages else "-"
    return {
        "caster": f"{state.get('caster', '-')}/{state.get('mountpoint', '-')}"[:40],
        "state": what if state.get("state") == "streaming" and not why else Alert(what),
        "rate": fmt_unit(state.get("bytes_per_s"), "B/s", 0),
        "types": types[:40],
        "base": str(state.get("base_id") or "-"),
        # not "age": the monitor's own column says how old the state sample is
        "last message": _last_message(number(state.get("last_message_age_s"))),
    }


def _last_message(age: float | None) -> str:
    shown = fmt_age(age)
    return Alert(f"{shown} STALE") if age is not None and age > CORRECTIONS_STALE_S else shown
