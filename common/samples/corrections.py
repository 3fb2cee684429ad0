"""The corrections sample, viena.gnss.corrections/1, on viena/<car>/gnss/corrections.

The NTRIP client publishes what one read from the caster brought: with the format RTCMV3,
whole RTCM 3 frames whose CRC-24Q checked (bytes between frames are never published), with
their message numbers and the reference station id they name; with RAW, the bytes as they
came (RTCM 2.x, CMR, RTCA: the receiver frames them). The GNSS service writes ``data`` to
its receiver as it is.
"""
from __future__ import annotations

from typing import NamedTuple

from viena.common.display import fmt_age, fmt_num
from viena.common.schema import F, Invalid, Schema

FORMATS = ("RTCMV3", "RAW")


def _bytes(v):
    """Bytes (msgpack bin); a bytearray or memoryview is taken as bytes."""
    if type(v) is bytes:
        return v
    if isinstance(v, (bytearray, memoryview)):
        return bytes(v)
    raise Invalid("expected bytes", v)


CORRECTIONS = Schema("viena.gnss.corrections/1", {
    "t": F.time,                        # host clock when the bytes were read, UTC ns
    "seq": F.int,
    "source": F.str,                    # "host:port/mountpoint"
    "data": _bytes,                     # whole RTCM 3 frames (RTCMV3), else the bytes as read
    "format": F.enum(*FORMATS),
    "types": F.list(F.int),             # RTCM 3 message numbers in data, in order ([] for RAW)
    "base_id": F.optional(F.str),       # reference station id (DF003) named in data, if any
})


class Corrections(NamedTuple):
    """A corrections sample as a consumer (the GNSS service) reads it."""

    t: int
    seq: int
    source: str
    data: bytes
    format: str
    types: tuple[int, ...]
    base_id: str | None


_FIELDS = CORRECTIONS.reader(*Corrections._fields, defaults={"types": [], "base_id": None})


def read_corrections(sample) -> Corrections:
    """The Corrections in a decoded sample; a FieldError names the field that is wrong."""
    t, seq, source, data, fmt, types, base_id = _FIELDS(sample)
    return Corrections(t, seq, source, data, fmt, tuple(types), base_id)


def corrections_sample(t_ns: int, seq: int, source: str, data: bytes, fmt: str,
                       types=(), base_id: str | None = None) -> dict:
    return {"t": t_ns, "seq": seq, "source": source, "data": bytes(data), "format": fmt,
            "types": list(types), "base_id": base_id}


def monitor_view(sample: dict, age_s: float | None = None) -> dict[str, str]:
    """How the monitor shows a corrections sample (any map)."""
    data = sample.get("data")
    types = sample.get("types")
    shown = ",".join(str(t) for t in dict.fromkeys(types)) if isinstance(types, list) and types else "-"
    return {
        "source": str(sample.get("source") or "-")[:40],
        "format": str(sample.get("format") or "-"),
        "bytes": fmt_num(len(data)) if isinstance(data, (bytes, bytearray)) else "-",
        "types": shown[:40],
        "base": str(sample.get("base_id") or "-"),
        "age": fmt_age(age_s),
    }
