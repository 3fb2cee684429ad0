"""The steering state sample, published at >= 50 Hz on viena/<car>/steering/state: its
schema, and how it is read off the core."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from viena.common.display import fields_view
from viena.common.schema import F, Schema
from viena.services.steering.model.trips import TripCause

if TYPE_CHECKING:                     # the schema alone must not pull in the CAN stack
    from viena.services.steering.model.actions import DriveReading
    from viena.services.steering.model.core import SteeringCore

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
    "trip": F.str,                            # why it last stopped, as text: begins with its cause's label
    "fault": F.str,                           # the drive's active fault ("" when none)
    "emcy": F.str,                            # the last EMCY seen, with its name
    "limits": F.list(F.str),                  # limits active on the last setpoint
    "decision": F.optional(F.map),            # {"status", "reason"} of the last setpoint
    "calibration": F.map,                     # state, min/max/zero/span qc, range_deg, problem
    # the speed envelope now (model/lateral.py, model/speed.py); optional: older states lack them
    "speed_mps": F.optional(F.float),         # the speed the envelope uses
    "speed_source": F.optional(F.str),        # estimator[+gnss0...] or conservative
    "speed_problem": F.optional(F.str),       # why conservative ("" when the sources are used)
    "max_wheel_deg": F.optional(F.float),     # widest target either way at that speed (None: no limit)
    "max_rate_deg_s": F.optional(F.float),    # fastest target rate there (slew or lateral jerk)
    "engaging": F.optional(F.bool),           # the stricter limits of the first seconds after an arm
    # why it last stopped (model/trips.py TripCause; None: no trip since the arm); optional: older states lack it
    "trip_cause": F.optional(F.enum(*(cause.value for cause in TripCause))),
})

#: the fields a person at the monitor looks at first; the rest follow as they come
MONITOR_FIRST = ("phase", "armed", "owner", "angle_deg", "target_deg", "goal_deg", "watchdog",
                 "trip", "trip_cause", "fault", "drive_heartbeat", "ds402", "decision", "limits", "speed_mps",
                 "speed_source", "speed_problem", "max_wheel_deg", "max_rate_deg_s")


def monitor_view(state: dict) -> dict[str, str]:
    """How the monitor shows a steering state (any map): every field, MONITOR_FIRST first,
    since each may be the one that explains why the wheel does not move."""
    return fields_view(state, MONITOR_FIRST)


def sample(core: SteeringCore, now: float, wall_ns: int, reading: DriveReading, seq: int) -> dict:
    """The state as of `now` (`wall_ns` UTC), the `seq`-th sample."""
    fb = reading.feedback
    cal, env = core.calibration, core.envelope
    fresh = core.fresh(fb, now)
    last = env.last
    # armed: the speed and limits the target was made at (a tick ago at most); else as of now
    speed, lim = env.used if env.armed and env.used is not None else env.limits_now(now)
    rate = lim.rate_deg_s(env.target_deg if env.armed and env.target_deg is not None else 0.0)
    return {
        "t": wall_ns,
        "seq": seq,
        "phase": core.phase.value,
        "armed": env.armed,
        "owner": env.owner,
        "angle_deg": cal.measured_deg(fb.position_qc) if cal is not None and fresh else None,
        "angle_qc": fb.position_qc if fresh else None,
        "target_deg": env.target_deg if env.armed else None,
        "target_qc": core.target_qc if env.armed else None,
        "goal_deg": env.goal_deg,
        "ds402": fb.state if fresh else "unknown",
        "statusword": fb.statusword,
        "following_error_qc": fb.following_error_qc,
        "drive_heartbeat": "ok" if core.drive_alive else "lost",
        "watchdog": "tripped" if env.trip_cause is TripCause.WATCHDOG else "ok",
        "trip": env.tripped,
        "fault": core.fault_text(fb, now),
        "emcy": core.emcy,
        "limits": list(last.limits) if last is not None else [],
        "decision": {"status": last.status, "reason": last.reason} if last is not None else None,
        "calibration": core.calibration_state(),
        "speed_mps": speed.mps,
        "speed_source": speed.source,
        "speed_problem": speed.problem,
        "max_wheel_deg": lim.max_wheel_deg if math.isfinite(lim.max_wheel_deg) else None,
        "max_rate_deg_s": rate,
        "engaging": lim.engaging,
        "trip_cause": env.trip_cause.value if env.trip_cause is not None else None,
    }
