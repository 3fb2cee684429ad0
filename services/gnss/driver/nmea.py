"""NMEA 0183 GNSS receivers (a u-blox NEO-M8N or ZED-F9P, SiRF...): GGA, RMC, VTG, GSA (and
GSV for the satellites in view), checksums verified by pynmea2 (docs/sensors.md#nmea-receivers).

Sentences are grouped into epochs by their UTC time. An epoch is handed on as soon as it
holds every sentence (talker and type) the previous epoch held, so there is no wait for the
next epoch's first sentence, or, failing that, when the next epoch begins.

Multi-constellation receivers speak with several talkers in one epoch: GN for the combined
solution, GP (GPS), GL (GLONASS), GA (Galileo), GB/BD (BeiDou), GQ (QZSS). One epoch makes
one fix: the GN position when there is one, else the best single-talker solution (highest
quality, most satellites) - never whichever GGA came last. Satellites used are the union of
every system's GSA; satellites tracked the union of every GSV (so tracked >= used).

Dates: a receiver hit by the GPS week rollover (the 10-bit week wraps every 1024 weeks,
19.6 years) reports dates 1024 weeks back (1999 for 2019). A date before 2024 is checked
against the host clock, when the host clock itself is sane (2024 or later): 1024 or 2048
weeks later lands within a day of it -> corrected and counted; otherwise the fix is
marked with the reason and not used as valid.
"""
from __future__ import annotations

import calendar
import datetime as dt
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pynmea2

from viena.common import clock
from viena.common.link import open_link
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
    talker: str = "GP"              # the talker whose GGA gave the position
    diff_age_s: float | None = None  # GGA: age of the differential corrections (s), if any
    station_id: str | None = None   # GGA: the differential base station's id, if any
    sentences: tuple[str, ...] = ()  # the sentence types the epoch held (GGA, RMC, ...)
    talkers: tuple[str, ...] = ()    # who spoke in it (GN, GP, GL, GA, GB ...)
    date_problem: str | None = None  # why the date cannot be trusted (the fix is not valid)

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
    rollover_corrected: int = 0     # dates moved on by 1024 weeks (the host clock agreed)
    rollover_refused: int = 0       # dates before 2024 the host clock could not settle


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


#: no epoch of this software's life is older: an earlier date is a wrapped GPS week
MIN_PLAUSIBLE_DATE = dt.date(2024, 1, 1)
MIN_PLAUSIBLE_S = calendar.timegm(MIN_PLAUSIBLE_DATE.timetuple())
WEEK_ROLLOVER_S = 1024 * 7 * 86400
TALKER_SYSTEMS = {"GP": "GPS", "GL": "GLONASS", "GA": "Galileo", "GB": "BeiDou", "BD": "BeiDou",
                  "GQ": "QZSS", "GI": "NavIC", "GN": "GNSS"}
#: NMEA 4.10 system ids (GSA and GSV's last field) -> talker
SYSTEM_IDS = {"1": "GP", "2": "GL", "3": "GA", "4": "GB", "5": "GQ", "6": "GI"}


@dataclass
class _Epoch:
    time: dt.time
    seen: set = field(default_factory=set)          # talker + sentence type (+ system)
    types: set = field(default_factory=set)
    talkers: set = field(default_factory=set)
    values: dict = field(default_factory=dict)      # RMC, VTG, GSA DOPs
    gga: dict = field(default_factory=dict)         # talker -> GGA values
    used: set = field(default_factory=set)          # (system, prn) from every GSA
    tracked: set = field(default_factory=set)       # (system, prn) from every GSV
    in_view: dict = field(default_factory=dict)     # talker -> GSV's own count
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
        kind: str = getattr(msg, "sentence_type", "")
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
        _collect(epoch, kind, msg.talker, values)
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
        if not epoch.gga:
            self.stats.incomplete_epochs += 1
            return []
        self.stats.epochs += 1
        talker, gga = _best_gga(epoch.gga)
        v = {**epoch.values, **gga}
        used = len(epoch.used) if epoch.used else gga.get("sats_used")
        tracked = len(epoch.tracked) if epoch.tracked else (sum(epoch.in_view.values()) or None)
        if tracked is not None and used is not None:
            tracked = max(tracked, used)
        utc_ns, problem = self._utc_ns(epoch.time, epoch.t_host_ns)
        return [NmeaFix(
            utc_ns=utc_ns, t_host_ns=epoch.t_host_ns,
            quality=v["quality"], lat_deg=v.get("lat"), lon_deg=v.get("lon"),
            height_msl_m=v.get("alt"), geoid_sep_m=v.get("geoid_sep"),
            sats_used=used, sats_in_view=tracked,
            hdop=v.get("hdop"), pdop=v.get("pdop"), vdop=v.get("vdop"),
            fix_mode=v.get("fix_mode"), rmc_valid=v.get("rmc_valid"),
            speed_mps=v.get("speed"), course_deg=v.get("course"), talker=talker,
            diff_age_s=gga.get("diff_age"), station_id=gga.get("station_id"),
            sentences=tuple(sorted(epoch.types)), talkers=tuple(sorted(epoch.talkers)),
            date_problem=problem)]

    def _utc_ns(self, time: dt.time, t_host_ns: int) -> tuple[int, str | None]:
        """(UTC ns, why the date cannot be trusted or None). Date from RMC; without one,
        the host's date, taking the day that puts the epoch nearest the host clock (an
        epoch at 23:59:59.9 read at 00:00:00.1)."""
        seconds = time.hour * 3600 + time.minute * 60 + time.second + time.microsecond / 1e6
        host_s = t_host_ns / 1e9
        if self._date is None:
            day = math.floor(host_s / 86400) * 86400
            best = min((day + k * 86400 + seconds for k in (-1, 0, 1)), key=lambda t: abs(t - host_s))
            return int(round(best * 1e9)), None
        utc_s = calendar.timegm(self._date.timetuple()) + seconds
        if self._date >= MIN_PLAUSIBLE_DATE or host_s < MIN_PLAUSIBLE_S:
            # a recent date, or no sane host clock to judge it by (the receiver is then the
            # best clock there is)
            return int(round(utc_s * 1e9)), None
        for wraps in (1, 2):
            corrected = utc_s + wraps * WEEK_ROLLOVER_S
            if abs(corrected - host_s) < 86400:
                self.stats.rollover_corrected += 1
                return int(round(corrected * 1e9)), None
        self.stats.rollover_refused += 1
        return int(round(utc_s * 1e9)), (
            f"receiver date {self._date} is before {MIN_PLAUSIBLE_DATE} and no whole number of "
            f"1024-week GPS rollovers from the host clock: its week has wrapped, by how much unknown")


def _collect(epoch: _Epoch, kind: str, talker: str, values: dict) -> None:
    """File one sentence's values in its epoch, by talker where talkers differ."""
    epoch.talkers.add(talker)
    if kind != "GSV" or values["last"]:
        epoch.types.add(kind)
    if kind == "GGA":
        epoch.gga[talker] = values
        epoch.seen.add(talker + kind)
    elif kind == "GSA":
        system = SYSTEM_IDS.get(values.pop("system_id", None) or "", talker)
        epoch.used.update((system, prn) for prn in values.pop("prns"))
        fix_mode = values.get("fix_mode")
        if fix_mode is not None and (epoch.values.get("fix_mode") or 0) > fix_mode:
            values.pop("fix_mode")              # the best system's fix mode stands
        epoch.values.update({k: v for k, v in values.items() if v is not None})
        epoch.seen.add(talker + kind + (system if system != talker else ""))
    elif kind == "GSV":
        epoch.tracked.update((talker, prn) for prn in values["prns"])
        if values["in_view"] is not None:
            epoch.in_view[talker] = values["in_view"]
        if values["last"]:
            epoch.seen.add(talker + kind)
    else:
        epoch.values.update(values)
        epoch.seen.add(talker + kind)


def _best_gga(by_talker: dict) -> tuple[str, dict]:
    """The combined (GN) solution if the receiver sent one, else the best single system's."""
    if "GN" in by_talker:
        return "GN", by_talker["GN"]
    return max(by_talker.items(), key=lambda kv: (kv[1].get("quality") or 0, kv[1].get("sats_used") or 0,
                                                    kv[0] == "GP"))


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
              "geoid_sep": _num(msg.geo_sep),
              # the differential part (fields 13, 14), empty or absent without corrections
              "diff_age": _num(getattr(msg, "age_gps_data", None)),
              "station_id": (getattr(msg, "ref_station_id", None) or "").strip() or None}
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
    prns = {int(p) for p in msg.data[2:14] if p.strip()}
    system_id = msg.data[17].strip() if len(msg.data) > 17 else None      # NMEA 4.10
    return {"fix_mode": _num(msg.mode_fix_type, int), "pdop": _num(msg.pdop),
            "hdop": _num(msg.hdop), "vdop": _num(msg.vdop), "prns": prns,
            "system_id": system_id}, None


def _gsv(msg):
    total, number = _num(msg.num_messages, int), _num(msg.msg_num, int)
    blocks = msg.data[3:]
    prns = {int(blocks[i]) for i in range(0, len(blocks) - 3, 4) if blocks[i].strip()}
    return {"in_view": _num(msg.num_sv_in_view, int), "prns": prns,
            "last": total is not None and number == total}, None


_HANDLERS = {"GGA": _gga, "RMC": _rmc, "VTG": _vtg, "GSA": _gsa, "GSV": _gsv}


class NmeaReceiver:
    """An NMEA receiver on a serial URL (any `open_link` takes); epochs to ``on_fix`` or to ``read()``."""

    def __init__(self, url: str, *, on_fix: Callable[[NmeaFix], None] | None = None,
                 on_link_error: Callable[[Exception], None] | None = None,
                 queue_size: int = 1000):
        self.url = url
        self._on_fix = on_fix
        self._on_link_error = on_link_error
        self._decoder = NmeaDecoder()
        self._fixes = clock.Queue(maxsize=queue_size)   # of NmeaFix
        self._link = open_link(url)
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

    def __enter__(self) -> NmeaReceiver:
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
            except clock.Full:
                self.dropped_fixes += 1

    def _on_error(self, exc: Exception) -> None:
        log.warning("%s: port failed: %s", self.url, exc)
        if self._on_link_error is not None:
            self._on_link_error(exc)
