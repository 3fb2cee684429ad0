"""What clients ask the steering service, as typed requests: parsed and checked here, once.

A payload (a map already decoded from JSON or msgpack) becomes one of:

    Arm(lease)                   {"arm": true} or, to renew, {"arm": true, "lease": L}
    Disarm(lease)                {"arm": false, "lease": L}
    Setpoint(angle_deg, ...)     {"angle_deg": x, "seq": n, "t": ns, "mac": M} or angle_rad:
                                 signed with the lease (model/signing.py), which it never carries
    Estop(by)                    anything: an e-stop is never refused for its form; a text
                                 `by` names the sender (as it says) for the log
    CalibrationRequest(action)   {} (status), {"restart": true}, {"finish": true}

or, when it is malformed, `Refused(reason)` (`BadSetpoint(reason)` for a setpoint: the
envelope records and logs those like any other verdict on a setpoint). Nothing here looks
at the time, the drive or who holds the wheel: that is `core.SteeringCore`'s job.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeGuard

from viena.common.text import printable
from viena.services.steering.model.signing import SEQ_MAX, setpoint_mac

ARM_FIELDS = frozenset({"arm", "lease"})
SETPOINT_FIELDS = frozenset({"angle_deg", "angle_rad", "t", "seq", "mac"})
CALIBRATION_ACTIONS = ("status", "restart", "finish")


@dataclass(frozen=True)
class Arm:
    lease: str | None = None          # the owner's lease renews the arm; None asks for one


@dataclass(frozen=True)
class Disarm:
    lease: str | None


@dataclass(frozen=True)
class Setpoint:
    angle_deg: float                  # finite; in degrees even when sent as angle_rad
    mac: str                          # the code the client made with its lease
    seq: int                          # the client's counter: grows with every setpoint
    t_ns: int | None = None           # when the client made it (ns UTC), for the age check
    unit: str = "deg"                 # the angle as sent, which is what was signed
    value: float | None = None        # (angle_deg itself when None)

    def signed_by(self, lease: str) -> str:
        """The code this setpoint would carry if `lease` had signed it."""
        value = self.angle_deg if self.value is None else self.value
        return setpoint_mac(lease, self.unit, value, self.seq, self.t_ns)


@dataclass(frozen=True)
class Estop:
    by: str = ""                      # who sent it, as the sender says (zenoh does not tell)


@dataclass(frozen=True)
class CalibrationRequest:
    action: str = "status"            # one of CALIBRATION_ACTIONS


@dataclass(frozen=True)
class Refused:
    """A request that cannot be understood; `reason` says why."""
    reason: str


@dataclass(frozen=True)
class BadSetpoint:
    """A malformed setpoint: the angle asked for, if one could be read, and why not."""
    reason: str
    requested_deg: float | None = None


Request = Arm | Disarm | Setpoint | Estop | CalibrationRequest | Refused | BadSetpoint


def parse_request(kind: str, payload) -> Request:
    """The typed request for a payload that came on `kind` (arm, setpoint, estop, calibration)."""
    parser = _PARSERS.get(kind)
    return parser(payload) if parser else Refused(f"unknown request {kind}")


def parse_arm(payload) -> Arm | Disarm | Refused:
    if not isinstance(payload, dict):
        return Refused("expected a map like {\"arm\": true}")
    unknown = sorted(str(k) for k in payload if k not in ARM_FIELDS)
    if unknown:
        return Refused(f"unknown field '{printable(unknown[0])}' (known: arm, lease)")
    arm, lease = payload.get("arm"), payload.get("lease")
    if not isinstance(arm, bool):
        return Refused("arm must be true or false")
    if lease is not None and not isinstance(lease, str):
        return Refused("lease must be text")
    return Arm(lease) if arm else Disarm(lease)


def parse_setpoint(payload) -> Setpoint | BadSetpoint:
    if not isinstance(payload, dict):
        return BadSetpoint(f"expected a map, got {type(payload).__name__}")
    if "lease" in payload:
        return BadSetpoint("a setpoint never carries the lease: sign it with the lease instead "
                           "(seq and mac: docs/steering.md#signed-setpoints)")
    unknown = sorted(str(k) for k in payload if k not in SETPOINT_FIELDS)
    if unknown:
        return BadSetpoint(f"unknown field '{printable(unknown[0])}' (known: angle_deg or angle_rad, seq, t, mac)")
    requested, why = _requested_deg(payload)
    if why or requested is None:                 # (no angle always says why)
        return BadSetpoint(why)
    mac, seq, t = payload.get("mac"), payload.get("seq"), payload.get("t")
    if mac is None:
        return BadSetpoint("missing mac: sign the setpoint with the lease the arm gave you", requested)
    if not isinstance(mac, str):
        return BadSetpoint("mac must be text (hex digits)", requested)
    if not _int64(seq):
        return BadSetpoint("seq must be an integer 0..2^63-1 that grows with every setpoint", requested)
    if t is not None and not _int64(t):
        return BadSetpoint("t must be an integer time in ns UTC", requested)
    unit = "deg" if "angle_deg" in payload else "rad"
    return Setpoint(requested, mac, seq, t, unit, float(payload[f"angle_{unit}"]))


def _int64(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= SEQ_MAX


def parse_estop(payload) -> Estop:
    by = payload.get("by") if isinstance(payload, dict) else None
    return Estop(printable(by, 32)) if isinstance(by, str) else Estop()


def parse_calibration(payload) -> CalibrationRequest | Refused:
    payload = payload or {}
    if not isinstance(payload, dict) or not set(payload) <= {"restart", "finish"}:
        return Refused("expected {} (status), {\"restart\": true} or {\"finish\": true}")
    if payload.get("restart") is True:
        return CalibrationRequest("restart")
    if payload.get("finish") is True:
        return CalibrationRequest("finish")
    return CalibrationRequest("status")


_PARSERS = {"arm": parse_arm, "setpoint": parse_setpoint, "estop": parse_estop,
            "calibration": parse_calibration}


def _requested_deg(payload: dict) -> tuple[float | None, str]:
    has_deg, has_rad = "angle_deg" in payload, "angle_rad" in payload
    if has_deg and has_rad:
        return None, "give angle_deg or angle_rad, not both"
    if not (has_deg or has_rad):
        return None, "missing angle_deg (or angle_rad)"
    name = "angle_deg" if has_deg else "angle_rad"
    value = payload[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None, f"{name} must be a number, got {type(value).__name__}"
    try:
        value = float(value)
    except OverflowError:              # an int beyond any float
        value = math.inf
    if not math.isfinite(value):
        return None, f"{name} is not finite"
    deg = value if has_deg else math.degrees(value)
    if not math.isfinite(deg):
        return None, f"{name} is not finite"
    return deg, ""
