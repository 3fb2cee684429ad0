"""viena.steering.state/1 on viena/<car>/steering/state (>= 50 Hz): its schema, the trip
causes it names, and its monitor view. The commands the steering takes (arm, setpoint,
calibration, estop) are typed requests in services/steering/model/requests.py."""
from __future__ import annotations

from enum import StrEnum

from viena.common.display import fields_view
from viena.common.schema import F, Schema


class TripCause(StrEnum):
    """Why the steering last stopped: the words on the wire (`trip_cause`). What each means,
    its deadline and what re-arms it: services/steering/model/trips.py TRIPS."""
    WATCHDOG = "watchdog"                        # no valid setpoint in time
    FEEDBACK_TIMEOUT = "feedback_timeout"        # no TPDO from the drive in time
    NO_POSITION = "no_position"                  # the envelope was given no measured angle
    DRIVE_HEARTBEAT = "drive_heartbeat"          # the drive's heartbeat stopped
    LIFE_GUARD = "life_guard"                    # the drive stopped hearing the host (EMCY 0x8130)
    DRIVE_FAULT = "drive_fault"                  # any other EMCY
    NOT_ENABLED = "not_enabled"                  # the drive left Operation Enabled
    ESTOP = "estop"                              # anyone asked
    LINK_LOST = "link_lost"                      # the CAN adapter went away
    DRIVE_REBOOTED = "drive_rebooted"            # boot-up message: configuration and counter gone
    DRIVE_SILENT = "drive_silent"                # silent long enough to have lost them
    NOT_OPERATIONAL = "not_operational"          # NMT state other than operational
    CALIBRATION_LOST = "calibration_lost"        # the calibration was dropped while armed
    SERVICE_STOPPING = "service_stopping"        # the service is shutting down


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
    # why it last stopped (TripCause above; None: no trip since the arm); optional: older states lack it
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
