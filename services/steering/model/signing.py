"""Setpoints signed with the lease: proof of ownership that never travels on the wire.

The arm's reply is the only message that carries a lease, and a reply goes to the one
client that asked. Every setpoint after it carries instead a message authentication code
(HMAC-SHA256, 128 bits) keyed by the lease over what the setpoint asks:

    {"angle_deg": 5.0, "seq": 17, "t": 1764270000000000000, "mac": "9f2c..."}

Whoever sees every byte on the car's network, or reads a recording of it, learns angles,
counters and codes, never the lease, and cannot make a code for an angle of their own.
Replaying a setpoint seen on the wire is refused too: `seq` must grow with every setpoint
of a lease (the steering remembers the last one it took); `t`, when given, must also be
fresh (`SafetySettings.max_age_s`).

The message signed is fixed-width and language-neutral, so any client can make it:

    b"viena.setpoint/1" | b"deg" or b"rad" | value as IEEE-754 float64, big-endian
                        | seq as int64 big-endian | t as int64 big-endian (0 when absent)

and the code is the first 16 bytes of HMAC-SHA256(key = the lease as UTF-8, that message),
as 32 lower-case hex digits.
"""
from __future__ import annotations

import hashlib
import hmac
import struct

DOMAIN = b"viena.setpoint/1"
MAC_HEX_DIGITS = 32
SEQ_MAX = 2 ** 63 - 1          # seq and t are int64 on the wire


def setpoint_mac(lease: str, unit: str, value: float, seq: int, t_ns: int | None) -> str:
    """The code of one setpoint (`unit` "deg" or "rad", the angle as sent)."""
    message = DOMAIN + unit.encode() + struct.pack(">dqq", float(value), seq, t_ns or 0)
    return hmac.digest(lease.encode(), message, hashlib.sha256).hex()[:MAC_HEX_DIGITS]     # one C call


def macs_match(expected: str, given: object) -> bool:
    """Compared in constant time: how long a wrong code took says nothing of the right one."""
    return isinstance(given, str) and hmac.compare_digest(expected.encode(), given.encode())


def signed_setpoint(lease: str, angle_deg: float | None = None, *, seq: int, angle_rad: float | None = None,
                    t_ns: int | None = None) -> dict:
    """A setpoint payload signed with `lease`: give `angle_deg` or `angle_rad`, and the
    sender's `seq` (`client.next_seq()` keeps one). A stamp `t_ns` (ns UTC) is sent only when given: the steering
    then refuses the setpoint once it is older than `max_age_s`, which holds only where the
    sender's clock agrees with the steering's; `seq` alone already refuses every replay."""
    if (angle_deg is None) == (angle_rad is None):
        raise ValueError("give angle_deg or angle_rad")
    unit, value = ("deg", angle_deg) if angle_deg is not None else ("rad", angle_rad)
    if value is None:                            # (one of the two is given: checked above)
        raise ValueError("give angle_deg or angle_rad")
    payload: dict[str, float | int | str] = {f"angle_{unit}": value, "seq": seq}
    if t_ns is not None:
        payload["t"] = t_ns
    payload["mac"] = setpoint_mac(lease, unit, value, seq, t_ns)
    return payload
