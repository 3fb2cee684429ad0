"""Which RTCM 3 messages a base sends when, as frames.

A message set maps each message number to its interval in seconds, as a caster's source
table states it ("1004(1),1005(10),1033(30)"): observables every epoch (1 Hz), the
antenna reference point every 10 s, the descriptors every 30 s, and the station messages
also at a client's connect, so a rover need not wait 10 s to learn where the base is.

- `RTK`: legacy GPS L1/L2 (1004) with 1005: what an OEM4 with RT-2 takes;
- `L1`: legacy GPS L1 only (1002) with 1005: for RT-20;
- `MSM`: MSM4 GPS and GLONASS (1074, 1084) with 1006: what modern casters serve, and what
  an OEM4 on firmware 2.310 cannot decode (it takes 1001-1006 only).
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping
from datetime import UTC, datetime, timedelta

from viena.services.gnss.driver.gpstime import GPS_EPOCH_UNIX_S, leap_seconds_at_gps

from . import rtcm
from .base import BaseStation, Epoch

RTK = {1004: 1, 1005: 10, 1033: 30}
L1 = {1002: 1, 1005: 10, 1033: 30}
MSM = {1074: 1, 1084: 1, 1006: 10, 1033: 30}
MESSAGE_SETS = {"rtk": RTK, "l1": L1, "msm": MSM}

OBSERVABLES = {1002: "GPS", 1004: "GPS", 1074: "GPS", 1084: "GLO"}
STATION = (1005, 1006, 1033)
#: the RTCM 3 version a message first appeared in (10403.1: 1001-1033; 10403.2: MSM)
_VERSION = {1002: "3.1", 1004: "3.1", 1005: "3.1", 1006: "3.1", 1033: "3.1", 1074: "3.2", 1084: "3.2"}


def check(messages: Mapping[int, float]) -> dict[int, float]:
    """A message set as a plain dict, or ValueError naming what this base cannot send."""
    unknown = sorted(set(messages) - set(_VERSION))
    if unknown:
        raise ValueError(f"the base twin sends {sorted(_VERSION)}, not {unknown}")
    for number, interval in messages.items():
        if not interval > 0:
            raise ValueError(f"message {number}: an interval is a positive number of seconds, not {interval}")
    return dict(messages)


def format_of(messages: Mapping[int, float]) -> str:
    """The STR format field: "RTCM 3.1", or "RTCM 3.2" with MSM."""
    return "RTCM " + max(_VERSION[n] for n in messages)


def format_details(messages: Mapping[int, float]) -> str:
    """The STR format details field: "1004(1),1005(10),1033(30)"."""
    return ",".join(f"{n}({interval:g})" for n, interval in messages.items())


def carrier_of(messages: Mapping[int, float]) -> int:
    """The STR carrier field: 0 no phase, 1 L1, 2 L1 and L2."""
    if any(n in messages for n in (1004, 1074, 1084)):
        return 2
    return 1 if 1002 in messages else 0


def nav_system_of(messages: Mapping[int, float]) -> str:
    systems = ["GPS"] + (["GLO"] if 1084 in messages else [])
    return "+".join(systems)


def due(messages: Mapping[int, float], gps_s: int, first: bool = False) -> list[int]:
    """The messages due at the whole second `gps_s`, station messages first (and all of them
    at a client's first epoch)."""
    def on_time(n: int) -> bool:
        return round(gps_s * 1000) % max(1, round(messages[n] * 1000)) == 0
    station = [n for n in STATION if n in messages and (first or on_time(n))]
    return station + [n for n in messages if n in OBSERVABLES and on_time(n)]


def glonass_time(gps_s: float) -> dict[str, int]:
    """MSM's GLONASS epoch fields: day of week (DF416, 0 = Sunday) and milliseconds of the
    day (DF034) in GLONASS time, UTC(SU) + 3 h."""
    gps_ns = round(gps_s * 1e9)
    utc_s = gps_s + GPS_EPOCH_UNIX_S - leap_seconds_at_gps(gps_ns)
    moscow = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(seconds=utc_s + 3 * 3600)
    midnight = moscow.replace(hour=0, minute=0, second=0, microsecond=0)
    return {"DF416": (moscow.weekday() + 1) % 7,
            "DF034": round((moscow - midnight).total_seconds() * 1000) % 86_400_000}


def build(number: int, base: BaseStation, epoch: Epoch, more: bool = False, glonass: bool = False) -> bytes:
    """One frame of message `number` from the base at `epoch`; `glonass`: the station
    serves GLONASS observables (the ARP's DF023 says so)."""
    if number in (1005, 1006):
        return rtcm.arp(number, base.station_id, tuple(base.ecef_m), base.antenna_height_m, glonass)
    if number == 1033:
        return rtcm.descriptors(base.station_id, base.descriptors)
    sats = [o.rtcm() for o in epoch.of(OBSERVABLES[number])]
    if number in (1002, 1004):
        return rtcm.legacy_observables(number, base.station_id, epoch.tow_ms, sats, more)
    if number == 1074:
        return rtcm.msm4(1074, base.station_id, {"DF004": epoch.tow_ms}, sats, rtcm.GPS_SIGNALS, more)
    return rtcm.msm4(1084, base.station_id, glonass_time(epoch.gps_s), sats, rtcm.GLONASS_SIGNALS, more)


class Frames:
    """A base's frames by epoch, made once for every client that asks (the last few epochs
    are kept): [(message number, frame bytes)]."""

    def __init__(self, base: BaseStation, keep: int = 8):
        self.base = base
        self._keep = keep
        self._epochs: OrderedDict[float, Epoch] = OrderedDict()
        self._frames: OrderedDict[tuple, bytes] = OrderedDict()
        self._lock = threading.Lock()

    def epoch(self, gps_s: float) -> Epoch:
        with self._lock:
            found = self._epochs.get(gps_s)
        if found is None:
            found = self.base.observe(gps_s)
            with self._lock:
                self._epochs[gps_s] = found
                while len(self._epochs) > self._keep:
                    self._epochs.popitem(last=False)
        return found

    def frame(self, number: int, gps_s: float, more: bool = False, glonass: bool = False) -> bytes:
        key = (number, gps_s, more) if number in OBSERVABLES else (number, glonass)
        with self._lock:
            found = self._frames.get(key)
        if found is None:
            epoch = self.epoch(gps_s) if number in OBSERVABLES else Epoch(gps_s, ())
            found = build(number, self.base, epoch, more, glonass)
            with self._lock:
                self._frames[key] = found
                while len(self._frames) > 4 * self._keep:
                    self._frames.popitem(last=False)
        return found

    def at(self, messages: Mapping[int, float], gps_s: int, first: bool = False) -> list[tuple[int, bytes]]:
        """The frames due at the whole second `gps_s`: station messages, then observables,
        each observable but the last flagged as followed by more of the same epoch."""
        numbers = due(messages, gps_s, first)
        observables = [n for n in numbers if n in OBSERVABLES]
        last = observables[-1] if observables else None
        glonass = any(OBSERVABLES[n] == "GLO" for n in messages if n in OBSERVABLES)
        return [(n, self.frame(n, gps_s, n in OBSERVABLES and n != last, glonass)) for n in numbers]


def stream(base: BaseStation, start_gps_s: int, seconds: int,
           messages: Mapping[int, float] = RTK) -> list[tuple[int, int, bytes]]:
    """What the base sends over `seconds` epochs from `start_gps_s` (the first one as to a
    client that just connected): [(gps second, message number, frame)]. For tests and
    benches that feed a receiver without a caster."""
    frames = Frames(base)
    return [(t, n, data) for t in range(start_gps_s, start_gps_s + seconds)
            for n, data in frames.at(messages, t, first=t == start_gps_s)]
