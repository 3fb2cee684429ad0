"""How each receiver's logs become viena.gnss.fix/1 samples (the schema is common/samples/fix.py).

NovAtel: BESTXYZ is a fix on its own; BESTPOS (geodetic) is joined with the BESTVEL of
the same epoch when that log is requested too. NMEA: one epoch (GGA + RMC/VTG + GSA) is
one fix; sigmas come from the DOPs times a user range error, since NMEA sends no sigmas.
Kept out of the model so that reading a fix loads no driver (tests/test_import_purity.py).
"""
from __future__ import annotations

import math
from typing import cast

import numpy as np
import pymap3d

from viena.common.geodesy import geodetic_of_ecef
from viena.common.samples.fix import is_no_fix
from viena.services.gnss.driver.gpstime import gps_to_utc_ns, utc_to_gps
from viena.services.gnss.driver.nmea import NmeaFix
from viena.services.gnss.driver.novatel import BestPos, BestVel, BestXyz, LogMessage, MessageId, TimeStatus

WGS84 = pymap3d.Ellipsoid.from_name("wgs84")
#: Below this the header's GPS time is not a time (the receiver counts from week 0).
_TIME_USABLE = TimeStatus.COARSE


def _finite(values) -> bool:
    return all(math.isfinite(v) for v in values)


def _times(header, t_host_ns: int) -> dict:
    """t from the header's GPS time, or the host clock when the receiver has no time."""
    usable = header.time_status >= _TIME_USABLE and header.week > 0
    t = gps_to_utc_ns(header.week, header.milliseconds) if usable else t_host_ns
    return {"t": t, "gps_week": header.week, "gps_ms": header.milliseconds,
            "t_host": t_host_ns, "latency_s": (t_host_ns - t) / 1e9,
            "time_status": TimeStatus.of(header.time_status)._name_}


def fix_from_bestxyz(msg: LogMessage, unit: str, seq: int) -> dict:
    """A fix from one BESTXYZ log, fields as the receiver sent them."""
    d = cast(BestXyz, msg.data)
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
    p = cast(BestPos, pos.data)
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
        v = cast(BestVel, vel.data)
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

