"""OEM4 logs the car uses: BESTXYZ (241), BESTPOS (42), BESTVEL (99), every field of
vol. 2 §3.4.3-3.4.6, statuses and types as named enums (docs/sensors.md#logs-used); and
VERSION (37, §3.4.94), asked once at start-up for the model and firmware.

A decoded log keeps its header, so the receiver's GPS time (week + ms) travels with the
data, and ``utc_ns`` gives the same instant in UTC.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, fields, replace
from typing import ClassVar

from viena.services.gnss.driver.gpstime import gps_to_utc_ns

from .commands import BodyError
from .enums import ComponentType, Datum, MessageId, PositionType, SolutionStatus
from .framing import Frame, Header, encode_frame

Vec3 = tuple[float, float, float]


def _station(raw: bytes) -> str:
    """A Char[n] field: the text up to its first NUL."""
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def _station_bytes(station: str) -> bytes:
    return station.encode("ascii", "replace")[:4].ljust(4, b"\0")


@dataclass(frozen=True)
class BestXyz:
    """Best available ECEF position and velocity (§3.4.6, 112-byte body)."""

    MESSAGE_ID: ClassVar[int] = MessageId.BESTXYZ
    _BODY: ClassVar[struct.Struct] = struct.Struct("<LLdddfffLLdddfff4sfffBBBB4s")

    pos_status: SolutionStatus
    pos_type: PositionType
    position_m: Vec3                # P-X, P-Y, P-Z (ECEF, WGS84)
    position_sigma_m: Vec3
    vel_status: SolutionStatus
    vel_type: PositionType
    velocity_mps: Vec3              # V-X, V-Y, V-Z
    velocity_sigma_mps: Vec3
    station_id: str = ""
    vel_latency_s: float = 0.0      # subtract from the time tag for the velocity's time
    diff_age_s: float = 0.0
    sol_age_s: float = 0.0
    sats_tracked: int = 0           # #obs
    sats_used: int = 0              # #GPSL1 used in the solution
    sats_l1_rtk: int = 0            # #L1 above the RTK mask
    sats_l2_rtk: int = 0            # #L2 above the RTK mask
    reserved: bytes = b"\0\0\0\0"

    def body(self) -> bytes:
        return self.pack(*(getattr(self, f.name) for f in fields(self)))

    @classmethod
    def pack(cls, pos_status: int, pos_type: int, position_m: Vec3, position_sigma_m: Vec3, vel_status: int,
             vel_type: int, velocity_mps: Vec3, velocity_sigma_mps: Vec3, station_id: str = "",
             vel_latency_s: float = 0.0, diff_age_s: float = 0.0, sol_age_s: float = 0.0, sats_tracked: int = 0,
             sats_used: int = 0, sats_l1_rtk: int = 0, sats_l2_rtk: int = 0, reserved: bytes = b"\0\0\0\0") -> bytes:
        """The body of a BestXyz of these fields (its fields, in order) without making one: the
        NovAtel twin writes one every epoch."""
        return cls._BODY.pack(
            pos_status, pos_type, *position_m, *position_sigma_m, vel_status, vel_type, *velocity_mps,
            *velocity_sigma_mps, _station_bytes(station_id), vel_latency_s, diff_age_s, sol_age_s,
            sats_tracked, sats_used, sats_l1_rtk, sats_l2_rtk, reserved)

    @classmethod
    def from_body(cls, body: bytes) -> BestXyz:
        v = _unpack(cls, body)
        return cls(SolutionStatus.of(v[0]), PositionType.of(v[1]), v[2:5], v[5:8],  # type: ignore[call-arg]
                   SolutionStatus.of(v[8]), PositionType.of(v[9]), v[10:13], v[13:16],
                   _station(v[16]), *v[17:24], v[24])


@dataclass(frozen=True)
class BestPos:
    """Best available geodetic position (§3.4.3, 72-byte body). Height is above mean sea
    level; add the undulation for the ellipsoidal height."""

    MESSAGE_ID: ClassVar[int] = MessageId.BESTPOS
    _BODY: ClassVar[struct.Struct] = struct.Struct("<LLdddfLfff4sffBBBB4s")

    pos_status: SolutionStatus
    pos_type: PositionType
    lat_deg: float
    lon_deg: float
    height_msl_m: float
    undulation_m: float
    datum: Datum = Datum.WGS84
    lat_sigma_m: float = 0.0
    lon_sigma_m: float = 0.0
    height_sigma_m: float = 0.0
    station_id: str = ""
    diff_age_s: float = 0.0
    sol_age_s: float = 0.0
    sats_tracked: int = 0
    sats_used: int = 0
    sats_l1_rtk: int = 0
    sats_l2_rtk: int = 0
    reserved: bytes = b"\0\0\0\0"

    @property
    def height_m(self) -> float:
        """Ellipsoidal height."""
        return self.height_msl_m + self.undulation_m

    def body(self) -> bytes:
        return self._BODY.pack(
            self.pos_status, self.pos_type, self.lat_deg, self.lon_deg, self.height_msl_m,
            self.undulation_m, self.datum, self.lat_sigma_m, self.lon_sigma_m,
            self.height_sigma_m, _station_bytes(self.station_id), self.diff_age_s,
            self.sol_age_s, self.sats_tracked, self.sats_used, self.sats_l1_rtk,
            self.sats_l2_rtk, self.reserved)

    @classmethod
    def from_body(cls, body: bytes) -> BestPos:
        v = _unpack(cls, body)
        return cls(SolutionStatus.of(v[0]), PositionType.of(v[1]), *v[2:6], Datum.of(v[6]),  # type: ignore[call-arg]
                   *v[7:10], _station(v[10]), *v[11:17], v[17])


@dataclass(frozen=True)
class BestVel:
    """Best available velocity (§3.4.5, 44-byte body): horizontal speed, track over
    ground from true north, vertical speed."""

    MESSAGE_ID: ClassVar[int] = MessageId.BESTVEL
    _BODY: ClassVar[struct.Struct] = struct.Struct("<LLffdddf")

    vel_status: SolutionStatus
    vel_type: PositionType
    latency_s: float
    diff_age_s: float
    hor_speed_mps: float
    track_deg: float
    vert_speed_mps: float
    reserved: float = 0.0

    def body(self) -> bytes:
        return self._BODY.pack(self.vel_status, self.vel_type, self.latency_s,
                               self.diff_age_s, self.hor_speed_mps, self.track_deg,
                               self.vert_speed_mps, self.reserved)

    @classmethod
    def from_body(cls, body: bytes) -> BestVel:
        v = _unpack(cls, body)
        return cls(SolutionStatus.of(v[0]), PositionType.of(v[1]), *v[2:])


@dataclass(frozen=True)
class Component:
    """One component of a VERSION log (§3.4.94, 108 bytes; formats in Table 89)."""

    _BODY: ClassVar[struct.Struct] = struct.Struct("<L16s16s16s16s16s12s12s")

    type: ComponentType = ComponentType.GPSCARD
    model: str = ""                 # e.g. "RT2WA": the enabled model (vol. 1 Table 3)
    psn: str = ""                   # product serial number
    hw_version: str = ""            # P-RS-CCC, e.g. "OEM4g2-2.00-X2T"
    sw_version: str = ""            # VV.RRR[Xxxx], e.g. "2.200A1"
    boot_version: str = ""
    comp_date: str = ""             # YYYY/MM/DD (the example's "2004/Feb/10")
    comp_time: str = ""             # HH:MM:SS

    def pack(self) -> bytes:
        sizes = (16, 16, 16, 16, 16, 12, 12)
        texts = (self.model, self.psn, self.hw_version, self.sw_version, self.boot_version,
                 self.comp_date, self.comp_time)
        return self._BODY.pack(self.type, *(t.encode("ascii", "replace")[:n] for t, n in zip(texts, sizes)))

    @classmethod
    def unpack_from(cls, body: bytes, offset: int) -> Component:
        v = cls._BODY.unpack_from(body, offset)
        return cls(ComponentType.of(v[0]), *(_station(raw) for raw in v[1:]))


@dataclass(frozen=True)
class Version:
    """VERSION: the receiver's components (§3.4.94): # comp, then 108 bytes each. A
    standard receiver has one, its GPSCARD."""

    MESSAGE_ID: ClassVar[int] = MessageId.VERSION
    _COUNT: ClassVar[struct.Struct] = struct.Struct("<l")

    components: tuple[Component, ...] = ()

    @property
    def card(self) -> Component | None:
        """The GPSCARD component (the receiver itself), or None."""
        return next((c for c in self.components if c.type == ComponentType.GPSCARD), None)

    def body(self) -> bytes:
        return self._COUNT.pack(len(self.components)) + b"".join(c.pack() for c in self.components)

    @classmethod
    def from_body(cls, body: bytes) -> Version:
        size = Component._BODY.size
        if len(body) < cls._COUNT.size:
            raise BodyError(f"VERSION body is {len(body)} bytes, expected at least 4")
        count, = cls._COUNT.unpack_from(body)
        if count < 0 or len(body) != cls._COUNT.size + count * size:
            raise BodyError(f"VERSION body is {len(body)} bytes, expected {cls._COUNT.size} + "
                            f"{size} x {count} components")
        return cls(tuple(Component.unpack_from(body, cls._COUNT.size + i * size) for i in range(count)))


def decode_version(frame: Frame) -> Version:
    """The VERSION log a frame carries; BodyError if its body is not one."""
    return Version.from_body(frame.body)


LOGS: dict[int, type[BestXyz] | type[BestPos] | type[BestVel]] = {c.MESSAGE_ID: c for c in (BestXyz, BestPos, BestVel)}


def _unpack(cls, body: bytes) -> tuple:
    if len(body) != cls._BODY.size:
        raise BodyError(f"{MessageId(cls.MESSAGE_ID).name} body is {len(body)} bytes, "
                        f"expected {cls._BODY.size}")
    return cls._BODY.unpack(body)


@dataclass(frozen=True)
class LogMessage:
    """A decoded log with the header it came in and the host time it arrived."""

    header: Header
    data: BestXyz | BestPos | BestVel
    t_host_ns: int = 0

    @property
    def name(self) -> str:
        return MessageId(self.header.message_id).name

    @property
    def gps_week(self) -> int:
        return self.header.week

    @property
    def gps_ms(self) -> int:
        return self.header.milliseconds

    @property
    def utc_ns(self) -> int:
        """The epoch's time tag in UTC (leap seconds applied)."""
        return gps_to_utc_ns(self.header.week, self.header.milliseconds)


def decode_log(frame: Frame) -> LogMessage | None:
    """The log a frame carries, None if this driver does not know its ID; BodyError if
    its body has the wrong size for its ID."""
    cls = LOGS.get(frame.header.message_id)
    if cls is None:
        return None
    return LogMessage(frame.header, cls.from_body(frame.body), frame.t_host_ns)


def encode_log(header: Header, data) -> bytes:
    """A complete log frame; the header's message ID is set from the data's type."""
    return encode_frame(replace(header, message_id=data.MESSAGE_ID), data.body())
