"""A caster's mountpoints, from the STR records of its source table (NTRIP 2.0, section 4.3;
pygnssutils parses the records, `get_mp_distance` gives the great-circle distance)."""
from __future__ import annotations

from typing import NamedTuple

from pygnssutils.helpers import get_mp_distance


class Mountpoint(NamedTuple):
    """One STR record, the fields a person picks a mountpoint by."""

    name: str
    identifier: str
    format: str             # RTCM 3.2, RTCM 2.3, CMR, ...
    details: str            # the messages and their periods: 1004(1),1005(10)
    nav_systems: str        # GPS+GLO+GAL
    country: str
    lat_deg: float | None
    lon_deg: float | None
    wants_gga: bool         # the caster needs the client's position (VRS, nearest base)
    network: bool           # a network solution (VRS), not a single base
    authentication: str     # N none, B basic, D digest
    bitrate: int | None

    def distance_km(self, lat_deg: float, lon_deg: float) -> float | None:
        """Great-circle distance from (lat, lon), None when the record has no position."""
        if self.lat_deg is None or self.lon_deg is None:
            return None
        return get_mp_distance(lat_deg, lon_deg, [self.name, *[""] * 7, self.lat_deg, self.lon_deg])


def _float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def mountpoints(records: list[list[str]]) -> list[Mountpoint]:
    """The STR records (fields after "STR", as pygnssutils gives them) as Mountpoints; a
    short record gets empty fields."""
    out = []
    for r in records:
        f = [*r, *[""] * max(0, 18 - len(r))]
        bitrate = f[16].strip()
        out.append(Mountpoint(
            name=f[0], identifier=f[1], format=f[2], details=f[3], nav_systems=f[5], country=f[7],
            lat_deg=_float(f[8]), lon_deg=_float(f[9]), wants_gga=f[10].strip() == "1",
            network=f[11].strip() == "1", authentication=f[14], bitrate=int(bitrate) if bitrate.isdigit() else None))
    return out


def by_distance(entries: list[Mountpoint], lat_deg: float, lon_deg: float) -> list[tuple[Mountpoint, float | None]]:
    """Each mountpoint with its distance, nearest first (those without a position last)."""
    pairs = [(m, m.distance_km(lat_deg, lon_deg)) for m in entries]
    return sorted(pairs, key=lambda p: (p[1] is None, p[1] or 0.0, p[0].name))
