"""A caster twin's mountpoint: the base station behind it, the messages it sends, and the
source-table line (STR) that describes it."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from . import protocol, schedule
from .base import BaseStation


@dataclass(eq=False)
class Mountpoint:
    """A mountpoint: its base station and what the base sends (message -> interval s)."""
    base: BaseStation
    messages: dict[int, float] = field(default_factory=lambda: dict(schedule.RTK))
    identifier: str = "Lisboa"
    country: str = "PRT"
    network: str = "VIENA"
    vrs: bool = False               # STR NMEA 1: nothing until a GGA, then a base at the rover
    latency_s: float = 0.2          # from the epoch to the base's frames reaching the caster

    def __post_init__(self) -> None:
        self.messages = schedule.check(self.messages)
        self._frames = schedule.Frames(self.base)
        self._bitrate: dict[tuple, int] = {}

    @classmethod
    def at(cls, origin: Sequence[float], baseline_m: float = 0.0, bearing_deg: float = 0.0,
           enu_m: Sequence[float] | None = None, station_id: int = 0, seed: int = 0,
           messages: str | Mapping[int, float] = "rtk", **kwargs) -> Mountpoint:
        """A mountpoint whose base stands `baseline_m` from `origin` at `bearing_deg` (or at
        `enu_m` from it), sending the message set "rtk", "l1", "msm" or one given."""
        chosen = schedule.MESSAGE_SETS[messages] if isinstance(messages, str) else messages
        base = BaseStation.at(origin, baseline_m, bearing_deg, enu_m, station_id=station_id, seed=seed)
        return cls(base, dict(chosen), **kwargs)

    @property
    def frames(self) -> schedule.Frames:
        return self._frames

    def entry(self, name: str, authentication: str) -> protocol.StreamEntry:
        lat, lon, _ = self.base.position
        return protocol.StreamEntry(
            name, self.identifier, schedule.format_of(self.messages), schedule.format_details(self.messages),
            schedule.carrier_of(self.messages), schedule.nav_system_of(self.messages), self.network,
            self.country, lat, lon, int(self.vrs), int(self.vrs), "VienaBaseTwin", authentication,
            self.bitrate())

    def bitrate(self) -> int:
        """Bits per second of the message set, from the frames of a sample epoch."""
        key = tuple(sorted(self.messages.items()))
        if key not in self._bitrate:
            sample = schedule.Frames(self.base)
            t = 1_400_000_000                                 # a fixed epoch: the table does not change
            bits = sum(len(sample.frame(n, t)) * 8 / interval for n, interval in self.messages.items())
            self._bitrate[key] = round(bits)
        return self._bitrate[key]
