"""The steering state sample, published at >= 50 Hz on viena/<car>/steering/state."""
from __future__ import annotations

from viena.common.schema import F, Schema

STATE = Schema("viena.steering.state/1", {
    "t": F.time,
    "seq": F.int,
    "phase": F.enum("connecting", "calibrating", "checking", "ready", "armed"),
    "armed": F.bool,
    "owner": F.optional(F.str),               # sha256 of the owner's lease, 12 hex digits
    "angle_deg": F.optional(F.float),         # measured, laser fit limited to +-limit_deg
    "angle_qc": F.optional(F.int),            # position actual value 0x6064
    "target_deg": F.optional(F.float),        # what the drive is told now
    "target_qc": F.optional(F.int),
    "goal_deg": F.optional(F.float),          # where the target is ramping to
    "ds402": F.str,                           # the drive's DS402 state
    "statusword": F.int,
    "following_error_qc": F.int,
    "drive_heartbeat": F.enum("ok", "lost"),
    "watchdog": F.enum("ok", "tripped"),
    "trip": F.str,                            # why it last stopped: watchdog, estop, EMCY ...
    "fault": F.str,                           # the drive's active fault ("" when none)
    "emcy": F.str,                            # the last EMCY seen, with its name
    "limits": F.list(F.str),                  # limits active on the last setpoint
    "decision": F.optional(F.map),            # {"status", "reason"} of the last setpoint
    "calibration": F.map,                     # state, min/max/zero/span qc, range_deg, problem
})
