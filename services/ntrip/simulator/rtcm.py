"""RTCM 3 messages made from their fields, with pyrtcm's own tables.

pyrtcm parses any message but builds one only from a payload. `payload()` is the other
direction: it walks the same payload definition pyrtcm's parser walks (rtcmtypes_get /
rtcmtypes_get_msm: the DF fields in order, repeating groups counted by an earlier field or
by the MSM masks) and packs each field with the width, type and scale of pyrtcm's
RTCM_DATA_FIELDS. Field values are named as pyrtcm names the parsed attributes ("DF004",
"DF009_03", "DF030_12"), in the units it gives them back (metres, not 0.02 m steps), so a
message built here and parsed by pyrtcm gives back what it was built from, to the field's
resolution. `frame()` puts a payload in its transport frame through pyrtcm
(`RTCMMessage(payload=...).serialize()`: preamble, length, CRC24Q), which parses it once
more on the way.

The builders below turn physical observables (ranges in metres, lock times in seconds) into
the fields of 1002/1004 (legacy GPS RTK observables), 1005/1006 (the base's antenna
reference point), 1033 (receiver and antenna descriptors) and MSM4 1074/1084 (GPS and
GLONASS multiple signal messages, which an OEM4 on firmware 2.310 cannot decode: it takes
RTCM 3 types 1001-1006 only, manual vol. 2 §3.4.73).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pyrtcm import RTCMMessage
from pyrtcm.rtcmtypes_core import (
    ALT,
    CELPRN,
    CELSIG,
    CHA,
    GROUP,
    INT,
    INTS,
    NCELL,
    NSAT,
    PRN,
    RTCM_DATA_FIELDS,
    STR,
)
from pyrtcm.rtcmtypes_get import RTCM_PAYLOADS_GET
from pyrtcm.rtcmtypes_get_msm import RTCM_PAYLOADS_GET_MSM

#: the speed of light (IS-GPS-200), m/s; one light-millisecond is the 1002/1004 modulus
C_MPS = 299_792_458.0
LIGHT_MS_M = C_MPS / 1000.0
GPS_L1_HZ = 1575.42e6
GPS_L2_HZ = 1227.60e6
#: MSM signal ids (RTCM 10403.3 table 3.5-91 and -96; pyrtcm.rtcmtables): L1 C/A, L2 P(Y)
#: semi-codeless for GPS, L1 C/A and L2 P for GLONASS
GPS_SIGNALS = {1: 2, 2: 10}
GLONASS_SIGNALS = {1: 2, 2: 9}


class EncodeError(ValueError):
    """A field that cannot be packed: missing, out of its range, or of a kind not supported."""


# -- the generic encoder --------------------------------------------------------------------------
def definition(identity: int | str) -> dict:
    """pyrtcm's payload definition of a message number (as RTCMMessage._get_dict finds it)."""
    identity = str(identity)
    if "1070" <= identity <= "1229":
        found = RTCM_PAYLOADS_GET_MSM.get(identity, {})
    else:
        found = RTCM_PAYLOADS_GET.get(identity, {})
    if not found:
        raise EncodeError(f"pyrtcm has no definition of message {identity}")
    return found


def payload(identity: int | str, values: Mapping[str, Any]) -> bytes:
    """The payload of message `identity` from its field values, named as pyrtcm's parsed
    attributes; DF002 (the message number) and reserved fields may be left out."""
    writer = _Writer(dict(values))
    writer.values.setdefault("DF002", int(identity))
    for name, spec in definition(identity).items():
        writer.attribute(name, spec)
    return writer.bytes()


def frame(data: bytes) -> bytes:
    """The transport frame of a payload (preamble 0xD3, 10-bit length, CRC24Q), by pyrtcm."""
    return RTCMMessage(payload=data).serialize()


def message(identity: int | str, values: Mapping[str, Any]) -> bytes:
    """A whole frame of message `identity` from its field values."""
    return frame(payload(identity, values))


class _Writer:
    """pyrtcm's RTCMMessage._do_attributes walk, writing bits instead of reading them."""

    def __init__(self, values: dict[str, Any]):
        self.values = values
        self.written: dict[str, Any] = {}
        self.bits = 0
        self.nbits = 0
        self.index: list[int] = []
        self.counts = {NSAT: 0, "NSig": 0, NCELL: 0}

    def bytes(self) -> bytes:
        pad = -self.nbits % 8
        return (self.bits << pad).to_bytes((self.nbits + pad) // 8, "big")

    def attribute(self, name: str, spec: Any) -> None:
        if name[-4:] == GROUP:
            self.group(spec)
        elif name[-4:] == ALT:
            (cond_name, cond_value), fields = spec
            if self.written.get(cond_name) == cond_value:
                for inner, inner_spec in fields.items():
                    self.attribute(inner, inner_spec)
        else:
            self.single(name)

    def group(self, spec: tuple) -> None:
        count_name, fields = spec
        if isinstance(count_name, int):
            size = count_name
        else:
            if "+" in count_name:
                count_name, levels = count_name.split("+")
                count_name += "".join(f"_{self.index[i]:02d}" for i in range(int(levels)))
            if count_name in self.counts:
                size = self.counts[count_name]
            elif count_name in self.written:
                size = self.written[count_name] + (1 if count_name == "IDF035" else 0)
            else:
                raise EncodeError(f"group size {count_name!r} is not a field written before it")
        self.index.append(0)
        for i in range(size):
            self.index[-1] = i + 1
            for inner, inner_spec in fields.items():
                self.attribute(inner, inner_spec)
        self.index.pop()

    def single(self, name: str) -> None:
        indexed = name + "".join(f"_{i:02d}" for i in self.index if i > 0)
        kind, size, scale, _ = RTCM_DATA_FIELDS[name]
        if kind in (PRN, CELPRN, CELSIG):               # derived from the masks: no bits
            return
        if kind == STR:
            raise EncodeError(f"{name}: concatenated strings are not supported")
        if name == "DF396":
            size = self.counts[NSAT] * self.counts["NSig"]
        value = self.values.get(indexed)
        if value is None:
            if not name.startswith("DF001"):
                raise EncodeError(f"field {indexed} ({RTCM_DATA_FIELDS[name][3]}) has no value")
            value = 0
        raw = _raw(indexed, kind, size, scale, value)
        self.bits = (self.bits << size) | raw
        self.nbits += size
        self.written[indexed] = raw if scale in (0, 1) else value
        if name == "DF394":
            self.counts[NSAT] = bin(raw).count("1")
        elif name == "DF395":
            self.counts["NSig"] = bin(raw).count("1")
        elif name == "DF396":
            self.counts[NCELL] = bin(raw).count("1")


def _raw(name: str, kind: str, size: int, scale: float, value: Any) -> int:
    """The field's bits as an unsigned integer of `size` bits."""
    if kind == CHA:
        number = ord(value) if isinstance(value, str) else int(value)
    elif scale not in (0, 1):
        number = round(value / scale)
    else:
        number = int(value)
    if kind == INT:
        low, high = -(1 << (size - 1)), (1 << (size - 1)) - 1
    elif kind == INTS:
        low, high = -((1 << (size - 1)) - 1), (1 << (size - 1)) - 1
    else:
        low, high = 0, (1 << size) - 1
    if not low <= number <= high:
        raise EncodeError(f"field {name} = {value!r} is outside its {size}-bit range")
    if kind == INT and number < 0:
        number += 1 << size
    elif kind == INTS and number < 0:
        number = (1 << (size - 1)) | -number
    return number


# -- the base station's messages ----------------------------------------------------------------------
def arp(number: int, station_id: int, ecef_m: Sequence[float], height_m: float = 0.0,
        glonass: bool = False) -> bytes:
    """1005 (stationary antenna reference point) or 1006 (the same with the antenna's height
    above the marker): where the base is, in ECEF metres."""
    if number not in (1005, 1006):
        raise EncodeError(f"an antenna reference point is message 1005 or 1006, not {number}")
    values = {"DF003": station_id, "DF021": 0, "DF022": 1, "DF023": int(glonass), "DF024": 0,
              "DF141": 0, "DF025": ecef_m[0], "DF142": 1, "DF026": ecef_m[1], "DF364": 0,
              "DF027": ecef_m[2]}
    if number == 1006:
        values["DF028"] = height_m
    return message(number, values)


@dataclass(frozen=True)
class Descriptors:
    """What 1033 says about the base: IGS antenna and receiver names, as a real base sends."""
    antenna: str = "NOV702GG        NONE"
    antenna_setup_id: int = 0
    antenna_serial: str = ""
    receiver: str = "NOVATEL OEM628"
    firmware: str = "OEM060700RN0000"
    receiver_serial: str = ""


DESCRIPTORS = Descriptors()


def descriptors(station_id: int, d: Descriptors = DESCRIPTORS) -> bytes:
    """1033: receiver and antenna descriptors (what a rover needs to pick antenna models)."""
    values: dict[str, Any] = {"DF003": station_id, "DF031": d.antenna_setup_id}
    for counter, name, text in (("DF029", "DF030", d.antenna), ("DF032", "DF033", d.antenna_serial),
                                ("DF227", "DF228", d.receiver), ("DF229", "DF230", d.firmware),
                                ("DF231", "DF232", d.receiver_serial)):
        text.encode("latin-1")                      # ISO 8859-1 characters only
        values[counter] = len(text)
        values.update({f"{name}_{i:02d}": ch for i, ch in enumerate(text, 1)})
    return message(1033, values)


@dataclass(frozen=True)
class Signal:
    """One signal of one satellite at an epoch: what the base measured."""
    pseudorange_m: float
    phase_range_m: float            # carrier phase times wavelength (ambiguity included)
    lock_s: float                   # time since the receiver locked on this carrier
    cnr_dbhz: float


@dataclass(frozen=True)
class SatSignals:
    """A satellite's signals at an epoch, by band (1: L1/G1, 2: L2/G2)."""
    sat: int                        # GPS PRN, or GLONASS slot number
    bands: Mapping[int, Signal] = field(default_factory=dict)


def legacy_lock_indicator(lock_s: float) -> int:
    """DF013/DF019: the 7-bit lock time indicator of RTCM 10403 table 3.4-2."""
    t = int(lock_s)
    if t >= 937:
        return 127
    for limit, offset, step in ((24, 0, 1), (48, 24, 2), (72, 120, 4), (96, 408, 8), (120, 1176, 16)):
        if t < limit * step - offset:
            return (t + offset) // step
    return (t + 3096) // 32


def msm_lock_indicator(lock_s: float) -> int:
    """DF402: the 4-bit MSM lock time indicator (table 3.5-74): 0 below 32 ms, then
    k for at least 2**(k+4) ms, up to 15."""
    ms = lock_s * 1000.0
    if ms < 32:
        return 0
    return min(15, int(math.floor(math.log2(ms))) - 4)


def _quantize(value: float, step: float) -> float:
    return round(value / step) * step


def legacy_observables(number: int, station_id: int, tow_ms: int, sats: Iterable[SatSignals],
                       more: bool = False) -> bytes:
    """1002 (L1) or 1004 (L1 and L2) extended GPS RTK observables (RTCM 10403 §3.5.2): the L1
    pseudorange modulo one light-millisecond with its integer millisecond ambiguity, the
    carrier phase ranges as differences from it, lock time indicators and CNRs. `more`: the
    synchronous flag (more observables of this epoch follow)."""
    if number not in (1002, 1004):
        raise EncodeError(f"extended GPS observables are 1002 or 1004, not {number}")
    sats = [s for s in sats if 1 in s.bands and (number == 1002 or 2 in s.bands)]
    values: dict[str, Any] = {"DF003": station_id, "DF004": int(tow_ms), "DF005": int(more),
                              "DF006": len(sats), "DF007": 0, "DF008": 0}
    for i, s in enumerate(sats, 1):
        l1 = s.bands[1]
        ambiguity = int(l1.pseudorange_m // LIGHT_MS_M)
        modulo = _quantize(l1.pseudorange_m - ambiguity * LIGHT_MS_M, 0.02)
        code1 = ambiguity * LIGHT_MS_M + modulo          # the L1 pseudorange the rover rebuilds
        values.update({f"DF009_{i:02d}": s.sat, f"DF010_{i:02d}": 0, f"DF011_{i:02d}": modulo,
                       f"DF012_{i:02d}": _quantize(l1.phase_range_m - code1, 0.0005),
                       f"DF013_{i:02d}": legacy_lock_indicator(l1.lock_s),
                       f"DF014_{i:02d}": ambiguity, f"DF015_{i:02d}": _quantize(l1.cnr_dbhz, 0.25)})
        if number == 1004:
            l2 = s.bands[2]
            values.update({f"DF016_{i:02d}": 3,              # L2 P(Y), semi-codeless ("2W")
                           f"DF017_{i:02d}": _quantize(l2.pseudorange_m - code1, 0.02),
                           f"DF018_{i:02d}": _quantize(l2.phase_range_m - code1, 0.0005),
                           f"DF019_{i:02d}": legacy_lock_indicator(l2.lock_s),
                           f"DF020_{i:02d}": _quantize(l2.cnr_dbhz, 0.25)})
    return message(number, values)


def msm4(number: int, station_id: int, epoch: Mapping[str, int], sats: Iterable[SatSignals],
         signals: Mapping[int, int], more: bool = False) -> bytes:
    """MSM4 of one constellation (1074 GPS, 1084 GLONASS: RTCM 10403.3 §3.5.12): rough
    ranges per satellite, fine pseudoranges and phase ranges per cell, in light
    milliseconds. `epoch`: the header's time fields ({"DF004": tow_ms} for GPS,
    {"DF416": day, "DF034": ms of day} for GLONASS); `signals`: band -> MSM signal id;
    `more`: the multiple message bit (another MSM of this epoch follows)."""
    if number not in (1074, 1084):
        raise EncodeError(f"this MSM4 encoder builds 1074 and 1084, not {number}")
    sats = sorted((s for s in sats if s.bands), key=lambda s: s.sat)
    sig_ids = sorted({signals[b] for s in sats for b in s.bands})
    values: dict[str, Any] = {"DF003": station_id, **epoch, "DF393": int(more), "DF409": 0,
                              "DF411": 0, "DF412": 0, "DF417": 0, "DF418": 0}
    values["DF394"] = sum(1 << (64 - s.sat) for s in sats)
    values["DF395"] = sum(1 << (32 - sid) for sid in sig_ids)
    cells = []
    mask = 0
    for s in sats:
        present = {signals[b]: sig for b, sig in s.bands.items()}
        for sid in sig_ids:
            mask = (mask << 1) | (sid in present)
            if sid in present:
                cells.append((s, present[sid]))
    values["DF396"] = mask
    rough = {}
    for i, s in enumerate(sats, 1):
        ref = s.bands[min(s.bands)].pseudorange_m / LIGHT_MS_M
        rough[s.sat] = _quantize(ref, 2.0 ** -10)
        whole = math.floor(rough[s.sat])
        values[f"DF397_{i:02d}"] = whole
        values[f"DF398_{i:02d}"] = rough[s.sat] - whole
    for i, (s, sig) in enumerate(cells, 1):
        values[f"DF400_{i:02d}"] = _quantize(sig.pseudorange_m / LIGHT_MS_M - rough[s.sat], 2.0 ** -24)
        values[f"DF401_{i:02d}"] = _quantize(sig.phase_range_m / LIGHT_MS_M - rough[s.sat], 2.0 ** -29)
        values[f"DF402_{i:02d}"] = msm_lock_indicator(sig.lock_s)
        values[f"DF420_{i:02d}"] = 0
        values[f"DF403_{i:02d}"] = max(1, min(63, round(sig.cnr_dbhz)))
    return message(number, values)


def msm_ranges(parsed: RTCMMessage) -> dict[tuple[int, str], tuple[float, float]]:
    """(satellite, signal code) -> (pseudorange m, phase range m) of a parsed MSM4: what a
    rover rebuilds from rough and fine ranges (for tests and tools)."""
    sats = {i: (int(getattr(parsed, f"PRN_{i:02d}")),
                getattr(parsed, f"DF397_{i:02d}") + getattr(parsed, f"DF398_{i:02d}"))
            for i in range(1, parsed.NSat + 1)}
    by_prn = {prn: rough for prn, rough in sats.values()}
    out = {}
    for i in range(1, parsed.NCell + 1):
        prn = int(getattr(parsed, f"CELLPRN_{i:02d}"))
        rough = by_prn[prn]
        out[(prn, getattr(parsed, f"CELLSIG_{i:02d}"))] = (
            (rough + getattr(parsed, f"DF400_{i:02d}")) * LIGHT_MS_M,
            (rough + getattr(parsed, f"DF401_{i:02d}")) * LIGHT_MS_M)
    return out


def message_number(data: bytes) -> int:
    """The message number (DF002) of a frame or of a payload."""
    body = data[3:] if data[:1] == b"\xd3" else data
    return body[0] << 4 | body[1] >> 4
