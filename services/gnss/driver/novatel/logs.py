"""OEM4 logs the car uses: BESTXYZ (241), BESTPOS (42), BESTVEL (99), every field of
vol. 2 §3.4.3-3.4.6, statuses and types as named enums (docs/sensors.md#logs-used); and
VERSION (37, §3.4.94), asked once at start-up for the model and firmware.

Each log is defined once, as its fields' wires (wire.py: struct code, count, enum table,
text): the driver decodes, and the twin encodes, through that one definition.

A decoded log keeps its header, so the receiver's GPS time (week + ms) travels with the
data, and ``utc_ns`` gives the same instant in UTC.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, replace
from typing import ClassVar

from viena.services.gnss.driver.gpstime import gps_to_utc_ns

from .commands import BodyError
from .enums import ComponentType, Datum, MessageId, PositionType, SolutionStatus
from .framing import Frame, Header, encode_frame
from .wire import BinaryRecord, wire

Vec3 = tuple[float, float, float]
RESERVED = b"\0\0\0\0"


class BestXyz(BinaryRecord):
    """Best available ECEF position and velocity (§3.4.6, 112-byte body)."""

    MESSAGE_ID = MessageId.BESTXYZ

    pos_status: SolutionStatus = wire("L", enum=SolutionStatus)
    pos_type: PositionType = wire("L", enum=PositionType)
    position_m: Vec3 = wire("d", count=3)               # P-X, P-Y, P-Z (ECEF, WGS84)
    position_sigma_m: Vec3 = wire("f", count=3)
    vel_status: SolutionStatus = wire("L", enum=SolutionStatus)
    vel_type: PositionType = wire("L", enum=PositionType)
    velocity_mps: Vec3 = wire("d", count=3)             # V-X, V-Y, V-Z
    velocity_sigma_mps: Vec3 = wire("f", count=3)
    station_id: str = wire("4s", text=True, default="")
    vel_latency_s: float = wire("f", default=0.0)       # subtract from the time tag for the velocity's time
    diff_age_s: float = wire("f", default=0.0)
    sol_age_s: float = wire("f", default=0.0)
    sats_tracked: int = wire("B", default=0)            # #obs
    sats_used: int = wire("B", default=0)               # #GPSL1 used in the solution
    sats_l1_rtk: int = wire("B", default=0)             # #L1 above the RTK mask
    sats_l2_rtk: int = wire("B", default=0)             # #L2 above the RTK mask
    reserved: bytes = wire("4s", default=RESERVED)


class BestPos(BinaryRecord):
    """Best available geodetic position (§3.4.3, 72-byte body). Height is above mean sea
    level; add the undulation for the ellipsoidal height."""

    MESSAGE_ID = MessageId.BESTPOS

    pos_status: SolutionStatus = wire("L", enum=SolutionStatus)
    pos_type: PositionType = wire("L", enum=PositionType)
    lat_deg: float = wire("d")
    lon_deg: float = wire("d")
    height_msl_m: float = wire("d")
    undulation_m: float = wire("f")
    datum: Datum = wire("L", enum=Datum, default=Datum.WGS84)
    lat_sigma_m: float = wire("f", default=0.0)
    lon_sigma_m: float = wire("f", default=0.0)
    height_sigma_m: float = wire("f", default=0.0)
    station_id: str = wire("4s", text=True, default="")
    diff_age_s: float = wire("f", default=0.0)
    sol_age_s: float = wire("f", default=0.0)
    sats_tracked: int = wire("B", default=0)
    sats_used: int = wire("B", default=0)
    sats_l1_rtk: int = wire("B", default=0)
    sats_l2_rtk: int = wire("B", default=0)
    reserved: bytes = wire("4s", default=RESERVED)

    @property
    def height_m(self) -> float:
        """Ellipsoidal height."""
        return self.height_msl_m + self.undulation_m


class BestVel(BinaryRecord):
    """Best available velocity (§3.4.5, 44-byte body): horizontal speed, track over
    ground from true north, vertical speed."""

    MESSAGE_ID = MessageId.BESTVEL

    vel_status: SolutionStatus = wire("L", enum=SolutionStatus)
    vel_type: PositionType = wire("L", enum=PositionType)
    latency_s: float = wire("f")
    diff_age_s: float = wire("f")
    hor_speed_mps: float = wire("d")
    track_deg: float = wire("d")
    vert_speed_mps: float = wire("d")
    reserved: float = wire("f", default=0.0)


class Component(BinaryRecord):
    """One component of a VERSION log (§3.4.94, 108 bytes; formats in Table 89)."""

    type: ComponentType = wire("L", enum=ComponentType, default=ComponentType.GPSCARD)
    model: str = wire("16s", text=True, default="")         # e.g. "RT2WA": the enabled model (vol. 1 Table 3)
    psn: str = wire("16s", text=True, default="")           # product serial number
    hw_version: str = wire("16s", text=True, default="")    # P-RS-CCC, e.g. "OEM4g2-2.00-X2T"
    sw_version: str = wire("16s", text=True, default="")    # VV.RRR[Xxxx], e.g. "2.200A1"
    boot_version: str = wire("16s", text=True, default="")
    comp_date: str = wire("12s", text=True, default="")     # YYYY/MM/DD (the example's "2004/Feb/10")
    comp_time: str = wire("12s", text=True, default="")     # HH:MM:SS


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
        return self._COUNT.pack(len(self.components)) + b"".join(c.body() for c in self.components)

    @classmethod
    def from_body(cls, body: bytes) -> Version:
        size = Component.CODEC.size
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
