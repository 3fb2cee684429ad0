"""The GNSS fix sample, viena.gnss.fix/1: its schema, its reader and its monitor view.

This module owns the schema (one module per schema: docs/dataflow.md#schemas) and loads no
driver: how each receiver's logs become a fix is services/gnss/fixes.py. A fix carries the
receiver's solution as it was sent (float64 ECEF, statuses by name) plus its times:
``t`` is the epoch's GPS time in UTC, ``t_host`` the host clock when the frame's last byte
arrived, ``latency_s`` their difference.
"""
from __future__ import annotations

from typing import NamedTuple

from viena.common.display import CORRECTIONS_STALE_S, Alert, fmt_num, norm, number
from viena.common.schema import F, FieldError, Schema

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
#: names (Table 47), which the NMEA path uses too (fixes.NMEA_QUALITY).
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


#: The receiver's "no solution" position (seen in the car's data): X=100, Y=Z=0.
NO_FIX_ECEF = (100.0, 0.0, 0.0)


def is_no_fix(position) -> bool:
    return tuple(position) == NO_FIX_ECEF
