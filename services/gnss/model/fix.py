"""The GNSS fix sample, viena.gnss.fix/1, and how each receiver's logs become one.

This module owns the schema (one module per schema: docs/dataflow.md#schemas). A fix carries the
receiver's solution as it was sent (float64 ECEF, statuses by name) plus its times:
``t`` is the epoch's GPS time in UTC, ``t_host`` the host clock when the frame's last byte
arrived, ``latency_s`` their difference.

NovAtel: BESTXYZ is a fix on its own; BESTPOS (geodetic) is joined with the BESTVEL of
the same epoch when that log is requested too. NMEA: one epoch (GGA + RMC/VTG + GSA) is
one fix; sigmas come from the DOPs times a user range error, since NMEA sends no sigmas.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pymap3d

from viena.common.display import CORRECTIONS_STALE_S, Alert, fmt_num, norm, number
from viena.common.geodesy import geodetic_of_ecef
from viena.common.schema import F, FieldError, Schema
from viena.services.gnss.driver.gpstime import gps_to_utc_ns, utc_to_gps
from viena.services.gnss.driver.nmea import NmeaFix
from viena.services.gnss.driver.novatel import BestPos, BestVel, BestXyz, LogMessage, MessageId, TimeStatus

FIX = Schema("viena.gnss.fix/1", {
    "t": F.time,                        # epoch, UTC ns (GPS time, leap seconds applied)
    "seq": F.int,
    "unit": F.str,
    "protocol": F.enum("novatel", "nmea"),
    "valid": F.bool,                    # SOL_COMPUTED and not the no-fix X=100,Y=Z=0
    "pos_status": F.str,                # solution status by name, e.g. SOL_COMPUTED
    "pos_type": F.str,                  # position type by name, e.g. SINGLE, NONE
    "vel_status": F.str,
    "vel_type": F.str,
    "ecef_m": F.vec(3),                 # float64 WGS84 ECEF
    "ecef_sigma_m": F.vec(3),
    "vel_ecef_mps": F.optional(F.vec(3)),
    "vel_sigma_mps": F.optional(F.vec(3)),
    "lat_deg": F.float,
    "lon_deg": F.float,
    "height_m": F.float,                # ellipsoidal
    "sats_tracked": F.int,
    "sats_used": F.int,
    "gps_week": F.int,
    "gps_ms": F.int,
    "t_host": F.time,                   # host clock at the frame's last byte, UTC ns
    "latency_s": F.float,               # t_host - t
    "vel_latency_s": F.float,           # receiver's velocity latency (subtract from t)
    "diff_age_s": F.optional(F.float),  # age of the differential corrections in use (s)
    "sol_age_s": F.optional(F.float),
    "base_id": F.optional(F.str),       # the differential base station's id, as the receiver names it
    "time_status": F.optional(F.str),   # receiver's GPS time quality (NovAtel), by name
    # the position's sigmas as the receiver gives them, when not (only) along ECEF axes:
    "enu_sigma_m": F.optional(F.vec(3)),  # along East, North, Up
    "sigma_h_m": F.optional(F.float),   # along each horizontal axis (East and North alike) ...
    "sigma_v_m": F.optional(F.float),   # ... and vertically (both or neither)
})

SOL_COMPUTED = "SOL_COMPUTED"

#: What a position type says of the fix's precision, coarsest first: the classes a reader
#: (the estimator's noise, the pilot's precision rule, the monitor) decides on. NovAtel's
#: names (Table 47), which the NMEA path uses too (NMEA_QUALITY).
SOLUTION_KINDS = ("none", "single", "sbas", "dgps", "float", "fixed")
_KIND_OF_TYPE = {
    "SINGLE": "single", "PROPAGATED": "single",
    "WAAS": "sbas", "CDGPS": "sbas", "OMNISTAR": "sbas",
    "PSRDIFF": "dgps",
    "L1_FLOAT": "float", "IONOFREE_FLOAT": "float", "NARROW_FLOAT": "float", "OMNISTAR_HP": "float",
    "OMNISTAR_XP": "float",
    "L1_INT": "fixed", "WIDE_INT": "fixed", "NARROW_INT": "fixed", "RTK_DIRECT_INS": "fixed",
    "FIXEDPOS": "fixed", "FIXEDHEIGHT": "fixed",
}


_RANK_OF_KIND = {kind: i for i, kind in enumerate(SOLUTION_KINDS)}


def solution_rank(kind: str | None) -> int:
    """A solution kind's place in SOLUTION_KINDS, higher is more precise (0 none ... 5
    fixed); -1 for an unknown kind, below every known one."""
    return -1 if kind is None else _RANK_OF_KIND.get(kind, -1)


def solution_kind(pos_type: str | None) -> str:
    """The precision class of a position type ("NARROW_INT" -> "fixed"); an unknown or
    missing type is "single" (what a receiver without corrections computes), NONE "none"."""
    if pos_type == "NONE":
        return "none"
    return _KIND_OF_TYPE.get(pos_type or "SINGLE", "single")


class Fix(NamedTuple):
    """A fix as a consumer reads it (the estimator): the fields the README's "Estimator"
    section lists, which any source may publish, checked by FIX's own checks. Made by
    `read_fix`. Vectors are tuples of floats (float64), not numpy arrays: the estimator
    reads them in scalar code, and arrays cost it a fifth of its throughput."""

    t: int
    unit: str
    valid: bool
    pos_status: str
    ecef_m: tuple[float, float, float]
    ecef_sigma_m: tuple[float, float, float] | None     # None when only ENU sigmas came
    vel_ecef_mps: tuple[float, float, float] | None
    vel_sigma_mps: tuple[float, float, float] | None
    vel_status: str
    vel_type: str
    vel_latency_s: float
    #: the sigmas along East, North, Up when the fix gave them so (enu_sigma_m, or
    #: sigma_h_m and sigma_v_m): better than ECEF ones, which lose the cross terms
    enu_sigma_m: tuple[float, float, float] | None = None
    #: satellites in the solution, when the source says (estimator's admission checks)
    sats_used: int | None = None
    #: the position type by name (SINGLE, PSRDIFF, NARROW_INT, ...): `kind` classes it
    pos_type: str = "SINGLE"
    #: age of the differential corrections in the solution (s), when it has any
    diff_age_s: float | None = None
    #: the differential base station's id, when the receiver says
    base_id: str | None = None

    @property
    def kind(self) -> str:
        """The solution's precision class: one of SOLUTION_KINDS."""
        return solution_kind(self.pos_type)

    @property
    def usable(self) -> bool:
        """The receiver calls the position a solution: valid and SOL_COMPUTED."""
        return self.valid and self.pos_status == SOL_COMPUTED

    @property
    def has_velocity(self) -> bool:
        """A velocity came with the fix and the receiver computed it."""
        return (self.vel_ecef_mps is not None and self.vel_status == SOL_COMPUTED
                and self.vel_type != "NONE")

    def without_velocity(self) -> Fix:
        return self._replace(vel_ecef_mps=None, vel_sigma_mps=None)


#: the fields a Fix is read from; a source may leave out those with a default here
#: (and the optional ones: no velocity), e.g. a receiver with no statuses beyond `valid`;
#: the sigmas may come along ECEF axes, along ENU, or as horizontal and vertical
_FIX_FIELDS = FIX.reader(*Fix._fields[:-5], "enu_sigma_m", "sigma_h_m", "sigma_v_m", "sats_used", "pos_type",
                         "diff_age_s", "base_id", defaults={
    "unit": "gnss", "pos_status": SOL_COMPUTED, "vel_status": SOL_COMPUTED, "vel_type": "",
    "vel_latency_s": 0.0, "ecef_sigma_m": None, "sats_used": None, "pos_type": "SINGLE"})


def read_fix(sample) -> Fix:
    """The Fix in a decoded sample from any source; a FieldError (a SampleError) names
    the field that is missing or wrong."""
    (t, unit, valid, status, ecef, sigma, vel, vel_sigma, vel_status, vel_type, latency,
     enu_sigma, sigma_h, sigma_v, sats, pos_type, diff_age, base_id) = _FIX_FIELDS(sample)
    if enu_sigma is None and (sigma_h is None) != (sigma_v is None):
        name = "sigma_v_m" if sigma_v is None else "sigma_h_m"
        raise FieldError(f"{FIX.name}: missing field {name!r} (sigma_h_m and sigma_v_m come "
                         f"together)", name)
    if enu_sigma is None and sigma_h is not None:
        enu_sigma = (sigma_h, sigma_h, sigma_v)
    if sigma is None and enu_sigma is None:
        raise FieldError(f"{FIX.name}: missing field 'ecef_sigma_m' (or enu_sigma_m, or "
                         f"sigma_h_m and sigma_v_m)", "ecef_sigma_m")
    return Fix(t, unit, valid, status, tuple(ecef), None if sigma is None else tuple(sigma),
               None if vel is None else tuple(vel), None if vel_sigma is None else tuple(vel_sigma),
               vel_status, vel_type, latency, None if enu_sigma is None else tuple(enu_sigma), sats,
               pos_type, diff_age, base_id or None)


def _corrections_cell(fix: dict) -> str:
    """The differential part of a fix: '1.4 s, base 2050'; '-' when it has none (a
    single-point fix's age is 0 or absent)."""
    age = number(fix.get("diff_age_s"))
    base = fix.get("base_id")
    pos_type = fix.get("pos_type")
    if not isinstance(pos_type, str) or solution_kind(pos_type) in ("none", "single"):
        return "-"
    shown = "-" if age is None else f"{age:.1f} s"
    shown = f"{shown}, base {base}" if isinstance(base, str) and base else shown
    return Alert(f"{shown} STALE") if age is not None and age > CORRECTIONS_STALE_S else shown


def monitor_view(fix: dict) -> dict[str, str]:
    """How the monitor shows a fix (any map: what came on a fix key)."""
    sigma = norm(fix.get("ecef_sigma_m"), 3)
    latency_s = number(fix.get("latency_s"))
    pos_type, pos_status = fix.get("pos_type"), fix.get("pos_status")
    # "NARROW_INT (fixed)": the type and what it means; the status only when it is not a solution
    solution = f"{pos_type} ({solution_kind(pos_type)})" if isinstance(pos_type, str) else "-"
    if pos_status is not None and pos_status != SOL_COMPUTED:
        solution = f"{pos_status}/{solution}"
    return {
        "fix": ("valid" if fix.get("valid") is True else "NO FIX" if fix.get("valid") is False else "?"),
        "solution": solution,
        "corrections": _corrections_cell(fix),
        "sats": f"{fmt_num(fix.get('sats_used'))}/{fmt_num(fix.get('sats_tracked'))}",
        "sigma": "-" if sigma is None else f"{sigma:.2f} m",
        "position": ("-" if number(fix.get("lat_deg")) is None else
                     f"{fmt_num(fix.get('lat_deg'), 7)}, {fmt_num(fix.get('lon_deg'), 7)}, "
                     f"{fmt_num(fix.get('height_m'), 1)} m"),
        "latency": "-" if latency_s is None else f"{latency_s * 1e3:.0f} ms",
    }

WGS84 = pymap3d.Ellipsoid.from_name("wgs84")
#: The receiver's "no solution" position (seen in the car's data): X=100, Y=Z=0.
NO_FIX_ECEF = (100.0, 0.0, 0.0)
#: Below this the header's GPS time is not a time (the receiver counts from week 0).
_TIME_USABLE = TimeStatus.COARSE


def is_no_fix(position) -> bool:
    return tuple(position) == NO_FIX_ECEF


def _finite(values) -> bool:
    return all(math.isfinite(v) for v in values)


def _times(header, t_host_ns: int) -> dict:
    """t from the header's GPS time, or the host clock when the receiver has no time."""
    usable = header.time_status >= _TIME_USABLE and header.week > 0
    t = gps_to_utc_ns(header.week, header.milliseconds) if usable else t_host_ns
    return {"t": t, "gps_week": header.week, "gps_ms": header.milliseconds,
            "t_host": t_host_ns, "latency_s": (t_host_ns - t) / 1e9,
            "time_status": TimeStatus.of(header.time_status)._name_}


def enu_sigma_to_ecef(sigma_enu, lat_deg: float, lon_deg: float) -> list[float]:
    """Standard deviations along ECEF axes of independent E, N, U errors."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    r = np.array([[-sl, -sp * cl, cp * cl],        # columns: E, N, U in ECEF
                  [cl, -sp * sl, cp * sl],
                  [0.0, cp, sp]])
    cov = r @ np.diag(np.square(sigma_enu)) @ r.T
    return [float(v) for v in np.sqrt(np.diag(cov))]


def enu_to_ecef_velocity(vel_enu, lat_deg: float, lon_deg: float) -> list[float]:
    u, v, w = pymap3d.enu2uvw(*vel_enu, lat_deg, lon_deg)
    return [float(u), float(v), float(w)]


def fix_from_bestxyz(msg: LogMessage, unit: str, seq: int) -> dict:
    """A fix from one BESTXYZ log, fields as the receiver sent them."""
    d: BestXyz = msg.data
    x, y, z = (float(v) for v in d.position_m)
    lat, lon, h = geodetic_of_ecef(x, y, z)
    sample = {
        "seq": seq, "unit": unit, "protocol": "novatel",
        "valid": (d.pos_status == 0 and d.pos_type != 0 and not is_no_fix(d.position_m)
                  and _finite(d.position_m)),
        # _name_ is the member's name as .name, without the enum property's cost (every fix)
        "pos_status": d.pos_status._name_, "pos_type": d.pos_type._name_,
        "vel_status": d.vel_status._name_, "vel_type": d.vel_type._name_,
        "ecef_m": [x, y, z], "ecef_sigma_m": [float(v) for v in d.position_sigma_m],
        "vel_ecef_mps": [float(v) for v in d.velocity_mps],
        "vel_sigma_mps": [float(v) for v in d.velocity_sigma_mps],
        "lat_deg": float(lat), "lon_deg": float(lon), "height_m": float(h),
        "sats_tracked": d.sats_tracked, "sats_used": d.sats_used,
        "vel_latency_s": float(d.vel_latency_s), "diff_age_s": float(d.diff_age_s),
        "sol_age_s": float(d.sol_age_s), "base_id": d.station_id or None,
    }
    sample.update(_times(msg.header, msg.t_host_ns))
    return sample


def fix_from_bestpos(pos: LogMessage, vel: LogMessage | None, unit: str, seq: int) -> dict:
    """A fix from BESTPOS, with the same epoch's BESTVEL when there is one."""
    p: BestPos = pos.data
    lat, lon, h = float(p.lat_deg), float(p.lon_deg), float(p.height_m)
    x, y, z = pymap3d.geodetic2ecef(lat, lon, h, WGS84)
    sample = {
        "seq": seq, "unit": unit, "protocol": "novatel",
        "valid": p.pos_status == 0 and p.pos_type != 0 and _finite((lat, lon, h)),
        "pos_status": p.pos_status.name, "pos_type": p.pos_type.name,
        "ecef_m": [float(x), float(y), float(z)],
        "ecef_sigma_m": enu_sigma_to_ecef((p.lon_sigma_m, p.lat_sigma_m, p.height_sigma_m),
                                          lat, lon),
        "enu_sigma_m": [float(p.lon_sigma_m), float(p.lat_sigma_m), float(p.height_sigma_m)],
        "lat_deg": lat, "lon_deg": lon, "height_m": h,
        "sats_tracked": p.sats_tracked, "sats_used": p.sats_used,
        "diff_age_s": float(p.diff_age_s), "sol_age_s": float(p.sol_age_s),
        "base_id": p.station_id or None, "vel_sigma_mps": None,
    }
    if vel is not None:
        v: BestVel = vel.data
        track = math.radians(v.track_deg)
        enu = (v.hor_speed_mps * math.sin(track), v.hor_speed_mps * math.cos(track),
               v.vert_speed_mps)
        sample.update(vel_status=v.vel_status.name, vel_type=v.vel_type.name,
                      vel_ecef_mps=enu_to_ecef_velocity(enu, lat, lon),
                      vel_latency_s=float(v.latency_s))
    else:
        sample.update(vel_status="INSUFFICIENT_OBS", vel_type="NONE", vel_ecef_mps=None,
                      vel_latency_s=0.0)
    sample.update(_times(pos.header, pos.t_host_ns))
    return sample


class NovatelFixBuilder:
    """Turns the logs of one receiver into fixes: each BESTXYZ, or each BESTPOS joined
    with its epoch's BESTVEL (held until that arrives or the next epoch begins)."""

    def __init__(self, unit: str, join_bestvel: bool = True):
        self.unit = unit
        self.join_bestvel = join_bestvel
        self._pos: LogMessage | None = None
        self._vel: LogMessage | None = None
        self._uses_bestxyz = False

    def add(self, msg: LogMessage) -> list[dict]:
        """Fixes completed by this log (without ``seq``: the publisher numbers them)."""
        mid = msg.header.message_id
        if mid == MessageId.BESTXYZ:
            self._uses_bestxyz = True
            return [fix_from_bestxyz(msg, self.unit, 0)]
        if self._uses_bestxyz:
            return []                   # BESTXYZ carries it all; BESTPOS/BESTVEL are extra
        key = (msg.header.week, msg.header.milliseconds)
        out = []
        held = self._pos
        if held is not None and (held.header.week, held.header.milliseconds) != key:
            out.append(fix_from_bestpos(held, None, self.unit, 0))
            self._pos = held = None
        if mid == MessageId.BESTPOS:
            vel = self._vel
            if vel is not None and (vel.header.week, vel.header.milliseconds) == key:
                out.append(fix_from_bestpos(msg, vel, self.unit, 0))
                self._vel = None
            elif self.join_bestvel:
                self._pos = msg
            else:
                out.append(fix_from_bestpos(msg, None, self.unit, 0))
        elif mid == MessageId.BESTVEL:
            if held is not None:
                out.append(fix_from_bestpos(held, msg, self.unit, 0))
                self._pos = None
            else:
                self._vel = msg
        return out


#: GGA quality -> (solution status, position type) in the NovAtel names every fix uses.
NMEA_QUALITY = {
    0: ("INSUFFICIENT_OBS", "NONE"),
    1: ("SOL_COMPUTED", "SINGLE"),
    2: ("SOL_COMPUTED", "PSRDIFF"),
    3: ("SOL_COMPUTED", "SINGLE"),
    4: ("SOL_COMPUTED", "NARROW_INT"),
    5: ("SOL_COMPUTED", "NARROW_FLOAT"),
    6: ("SOL_COMPUTED", "PROPAGATED"),
    7: ("SOL_COMPUTED", "FIXEDPOS"),
    9: ("SOL_COMPUTED", "WAAS"),        # NovAtel's GPGGA: "9 = WAAS" (OEM4 vol. 2 §3.4.17)
}
#: Vertical DOP assumed when GSA is missing, relative to HDOP (typical geometry).
VDOP_PER_HDOP = 1.6


def fix_from_nmea(fix: NmeaFix, unit: str, seq: int, uere_m: float = 3.0) -> dict | None:
    """A fix from one NMEA epoch; None when the receiver sent no position at all."""
    if fix.lat_deg is None or fix.lon_deg is None or fix.height_msl_m is None:
        return None
    status, kind = NMEA_QUALITY.get(fix.quality, ("INSUFFICIENT_OBS", "NONE"))
    lat, lon, h = fix.lat_deg, fix.lon_deg, fix.height_m
    x, y, z = pymap3d.geodetic2ecef(lat, lon, h, WGS84)
    hdop = fix.hdop if fix.hdop is not None else 1.0
    vdop = fix.vdop if fix.vdop is not None else VDOP_PER_HDOP * hdop
    sigma_h = hdop * uere_m / math.sqrt(2.0)
    sample = {
        "seq": seq, "unit": unit, "protocol": "nmea",
        # a date the rollover check could not settle is no time to fuse a fix at
        "valid": status == "SOL_COMPUTED" and fix.fix_mode != 1 and fix.date_problem is None,
        "pos_status": status, "pos_type": kind,
        "ecef_m": [float(x), float(y), float(z)],
        "ecef_sigma_m": enu_sigma_to_ecef((sigma_h, sigma_h, vdop * uere_m), lat, lon),
        "enu_sigma_m": [sigma_h, sigma_h, vdop * uere_m],
        "vel_sigma_mps": None,
        "lat_deg": lat, "lon_deg": lon, "height_m": h,
        "sats_tracked": fix.sats_in_view if fix.sats_in_view is not None else (fix.sats_used or 0),
        "sats_used": fix.sats_used or 0,
        "vel_latency_s": 0.0, "diff_age_s": fix.diff_age_s, "sol_age_s": None, "time_status": None,
        "base_id": fix.station_id,
    }
    if fix.speed_mps is not None and fix.rmc_valid is not False and status == "SOL_COMPUTED":
        course = math.radians(fix.course_deg or 0.0)
        enu = (fix.speed_mps * math.sin(course), fix.speed_mps * math.cos(course), 0.0)
        sample.update(vel_status="SOL_COMPUTED", vel_type=kind,
                      vel_ecef_mps=enu_to_ecef_velocity(enu, lat, lon))
    else:
        sample.update(vel_status="INSUFFICIENT_OBS", vel_type="NONE", vel_ecef_mps=None)
    week, ms = utc_to_gps(fix.utc_ns)
    sample.update(t=fix.utc_ns, gps_week=week, gps_ms=ms, t_host=fix.t_host_ns,
                  latency_s=(fix.t_host_ns - fix.utc_ns) / 1e9)
    return sample
