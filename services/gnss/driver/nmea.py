"""NMEA 0183 GNSS receivers (the u-blox NEO-M8N of the Titans car): GGA, RMC, VTG, GSA
(and GSV for the satellites in view), checksums verified by pynmea2.

Sentences are grouped into epochs by their UTC time. An epoch is handed on as soon as it
holds every sentence type the previous epoch held (so there is no wait for the next
epoch's first sentence), or, failing that, when the next epoch begins.
"""
from __future__ import annotations

import calendar
import datetime as dt
import logging
import math
import queue
from dataclasses import dataclass, field
from typing import Callable

import pynmea2

from viena.common.link import SerialLink
from viena.common.link_reader import LinkReader

log = logging.getLogger(__name__)

KNOT_MPS = 1852.0 / 3600.0
MAX_LINE = 120          # NMEA limits a sentence to 82 characters; allow some slack


@dataclass(frozen=True)
class NmeaFix:
    """One epoch of an NMEA receiver, in the receiver's own terms."""

    utc_ns: int
    t_host_ns: int
    quality: int                    # GGA fix quality: 0 none, 1 GPS, 2 DGPS/SBAS, 4 RTK ...
    lat_deg: float | None
    lon_deg: float | None
    height_msl_m: float | None
    geoid_sep_m: float | None       # ellipsoid height = MSL height + separation
    sats_used: int | None
    sats_in_view: int | None = None
    hdop: float | None = None
    pdop: float | None = None
    vdop: float | None = None
    fix_mode: int | None = None     # GSA: 1 no fix, 2 2-D, 3 3-D
    rmc_valid: bool | None = None   # RMC status A / V
    speed_mps: float | None = None
    course_deg: float | None = None
    talker: str = "GP"
    sentences: tuple[str, ...] = ()

    @property
    def has_position(self) -> bool:
        return self.quality > 0 and self.lat_deg is not None and self.lon_deg is not None

    @property
    def height_m(self) -> float | None:
        """Ellipsoidal height (MSL height + geoid separation)."""
        if self.height_msl_m is None:
            return None
        return self.height_msl_m + (self.geoid_sep_m or 0.0)


@dataclass
class NmeaStats:
    sentences: int = 0
    checksum_errors: int = 0
    parse_errors: int = 0           # not NMEA, bad fields, not ASCII, too long
    ignored_sentences: int = 0      # valid but not used (GLL, ZDA, ...)
    epochs: int = 0
    incomplete_epochs: int = 0      # ended without a GGA


def _num(value, kind=float):
    """A field as a number, None when empty; ValueError when it is not a number
    (pynmea2 hands back the raw text when its own conversion fails)."""
    if value is None or value == "":
        return None
    if kind is int and isinstance(value, float):
        raise ValueError(f"not an integer: {value!r}")
    number = kind(value)
    if kind is float and not math.isfinite(number):
        raise ValueError(f"non-finite field {value!r}")
    return number


@dataclass
class _Epoch:
    time: dt.time
    seen: set = field(default_factory=set)
    values: dict = field(default_factory=dict)
    t_host_ns: int = 0
    emitted: bool = False


class NmeaDecoder:
    """Bytes in, NmeaFix epochs out."""

    def __init__(self):
        self.stats = NmeaStats()
        self._line = bytearray()
        self._epoch: _Epoch | None = None
        self._expected: frozenset = frozenset()
        self._date: dt.date | None = None

    def reset(self) -> None:
        self._line.clear()
        self._epoch = None

    def feed(self, data: bytes, t_host_ns: int = 0) -> list[NmeaFix]:
        fixes: list[NmeaFix] = []
        self._line += data
        *lines, rest = self._line.split(b"\n")
        if len(rest) > MAX_LINE:        # no line end in sight: garbage, drop it
            self.stats.parse_errors += 1
            rest = b""
        self._line = bytearray(rest)
        for raw in lines:
            fixes.extend(self._sentence(raw.strip(), t_host_ns))
        return fixes

    def _sentence(self, raw: bytes, t_host_ns: int) -> list[NmeaFix]:
        if not raw:
            return []
        stats = self.stats
        start = raw.rfind(b"$")
        if start > 0:                   # garbage ran into this sentence: keep the sentence
            stats.parse_errors += 1
            raw = raw[start:]
        try:
            if len(raw) > MAX_LINE:
                raise pynmea2.ParseError("sentence too long", raw[:20])
            msg = pynmea2.parse(raw.decode("ascii"), check=True)
        except pynmea2.ChecksumError:
            stats.checksum_errors += 1
            return []
        except (pynmea2.ParseError, UnicodeDecodeError, ValueError, TypeError):
            stats.parse_errors += 1
            return []
        kind = getattr(msg, "sentence_type", None)
        handler = _HANDLERS.get(kind)
        if handler is None:
            stats.ignored_sentences += 1
            return []
        try:
            values, epoch_time = handler(msg)
        except (ValueError, TypeError, AttributeError, ArithmeticError) as exc:
            stats.parse_errors += 1
            log.debug("bad %s sentence %r: %s", kind, raw, exc)
            return []
        stats.sentences += 1
        out: list[NmeaFix] = []
        if epoch_time is not None and (self._epoch is None or self._epoch.time != epoch_time):
            out.extend(self._close_epoch())
            self._epoch = _Epoch(epoch_time)
        epoch = self._epoch
        if epoch is None or epoch.emitted:
            return out                 # timeless sentence before any epoch, or late extra
        if "date" in values:
            self._date = values["date"]
        if kind == "GSV":
            if values.pop("last", False):
                epoch.seen.add(kind)
        else:
            epoch.seen.add(kind)
        epoch.values.update(values)
        epoch.values.setdefault("talker", msg.talker)
        epoch.t_host_ns = t_host_ns
        if self._expected and self._expected <= epoch.seen:
            out.extend(self._emit(epoch))
        return out

    def _close_epoch(self) -> list[NmeaFix]:
        epoch = self._epoch
        if epoch is None:
            return []
        self._expected = frozenset(epoch.seen)
        if epoch.emitted:
            return []
        return self._emit(epoch)

    def _emit(self, epoch: _Epoch) -> list[NmeaFix]:
        epoch.emitted = True
        v = epoch.values
        if "GGA" not in epoch.seen:
            self.stats.incomplete_epochs += 1
            return []
        self.stats.epochs += 1
        return [NmeaFix(
            utc_ns=self._utc_ns(epoch.time, epoch.t_host_ns), t_host_ns=epoch.t_host_ns,
            quality=v["quality"], lat_deg=v.get("lat"), lon_deg=v.get("lon"),
            height_msl_m=v.get("alt"), geoid_sep_m=v.get("geoid_sep"),
            sats_used=v.get("sats_used"), sats_in_view=v.get("sats_in_view"),
            hdop=v.get("hdop"), pdop=v.get("pdop"), vdop=v.get("vdop"),
            fix_mode=v.get("fix_mode"), rmc_valid=v.get("rmc_valid"),
            speed_mps=v.get("speed"), course_deg=v.get("course"), talker=v["talker"],
            sentences=tuple(sorted(epoch.seen)))]

    def _utc_ns(self, time: dt.time, t_host_ns: int) -> int:
        """Date from RMC; without one, the host's date, taking the day that puts the
        epoch nearest the host clock (an epoch at 23:59:59.9 read at 00:00:00.1)."""
        seconds = time.hour * 3600 + time.minute * 60 + time.second + time.microsecond / 1e6
        if self._date is not None:
            day = calendar.timegm(self._date.timetuple())
            return int(round((day + seconds) * 1e9))
        host_s = t_host_ns / 1e9
        day = math.floor(host_s / 86400) * 86400
        best = min((day + k * 86400 + seconds for k in (-1, 0, 1)), key=lambda t: abs(t - host_s))
        return int(round(best * 1e9))


def _time(value) -> dt.time | None:
    if value is None or isinstance(value, dt.time):
        return value
    raise ValueError(f"bad time {value!r}")


def _latlon(msg) -> dict:
    if not msg.lat or not msg.lon:
        return {}
    if msg.lat_dir not in ("N", "S") or msg.lon_dir not in ("E", "W"):
        raise ValueError("bad hemisphere")
    return {"lat": msg.latitude, "lon": msg.longitude}


def _gga(msg):
    values = {"quality": _num(msg.gps_qual, int) or 0, "sats_used": _num(msg.num_sats, int),
              "hdop": _num(msg.horizontal_dil), "alt": _num(msg.altitude),
              "geoid_sep": _num(msg.geo_sep)}
    values.update(_latlon(msg))
    return values, _time(msg.timestamp)


def _rmc(msg):
    values = {"rmc_valid": msg.status == "A"}
    speed, course = _num(msg.spd_over_grnd), _num(msg.true_course)
    if speed is not None:
        values["speed"] = speed * KNOT_MPS
    if course is not None:
        values["course"] = course
    date = msg.datestamp
    if date is not None:
        if not isinstance(date, dt.date):
            raise ValueError(f"bad date {date!r}")
        values["date"] = date
    return values, _time(msg.timestamp)


def _vtg(msg):
    values = {}
    kmph, knots = _num(msg.spd_over_grnd_kmph), _num(msg.spd_over_grnd_kts)
    if kmph is not None:
        values["speed"] = kmph / 3.6
    elif knots is not None:
        values["speed"] = knots * KNOT_MPS
    course = _num(msg.true_track)
    if course is not None:
        values["course"] = course
    return values, None


def _gsa(msg):
    return {"fix_mode": _num(msg.mode_fix_type, int), "pdop": _num(msg.pdop),
            "hdop": _num(msg.hdop), "vdop": _num(msg.vdop)}, None


def _gsv(msg):
    total, number = _num(msg.num_messages, int), _num(msg.msg_num, int)
    return {"sats_in_view": _num(msg.num_sv_in_view, int),
            "last": total is not None and number == total}, None


_HANDLERS = {"GGA": _gga, "RMC": _rmc, "VTG": _vtg, "GSA": _gsa, "GSV": _gsv}


class NmeaReceiver:
    """An NMEA receiver on a pyserial URL; epochs to ``on_fix`` or to ``read()``."""

    def __init__(self, url: str, *, on_fix: Callable[[NmeaFix], None] | None = None,
                 on_link_error: Callable[[Exception], None] | None = None,
                 queue_size: int = 1000):
        self.url = url
        self._on_fix = on_fix
        self._on_link_error = on_link_error
        self._decoder = NmeaDecoder()
        self._fixes: queue.Queue[NmeaFix] = queue.Queue(maxsize=queue_size)
        self._link = SerialLink(url)
        self._reader = LinkReader(self._link, self._on_bytes, self._on_error, name="nmea")
        self.last_sentence_host_ns = 0
        self.dropped_fixes = 0

    @property
    def stats(self) -> NmeaStats:
        return self._decoder.stats

    @property
    def is_open(self) -> bool:
        return self._link.is_open

    def open(self, baudrate: int = 115200) -> None:
        self._reader.stop()           # an old reader must not see its port close
        self._decoder.reset()
        self._link.open(baudrate)
        self._reader.start()

    def close(self) -> None:
        self._reader.stop()
        self._link.close()

    def __enter__(self) -> "NmeaReceiver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def read(self, timeout: float | None = None) -> NmeaFix:
        return self._fixes.get(timeout=timeout)

    def _on_bytes(self, data: bytes, t_host_ns: int) -> None:
        before = self._decoder.stats.sentences
        fixes = self._decoder.feed(data, t_host_ns)
        if self._decoder.stats.sentences != before:
            self.last_sentence_host_ns = t_host_ns
        for fix in fixes:
            if self._on_fix is not None:
                self._on_fix(fix)
                continue
            try:
                self._fixes.put_nowait(fix)
            except queue.Full:
                self.dropped_fixes += 1

    def _on_error(self, exc: Exception) -> None:
        log.warning("%s: port failed: %s", self.url, exc)
        if self._on_link_error is not None:
            self._on_link_error(exc)
