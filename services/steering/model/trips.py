"""Why the steering stopped: every trip cause, and one table of what each means.

A trip disarms the envelope with a cause (`TripCause`); the core stops the drive the same way
for each (quick stop now, power off after `quickstop_hold_s`), and the state shows the cause
(`trip_cause`), its text (`trip`, which begins with the cause's label) and, for the setpoint
deadline, `watchdog: tripped`. `TRIPS` is read by the envelope and the core (the text), the
state, the monitor (through the state's view), the tests and docs/steering.md#watchdog-and-trips
(`markdown_table`, checked against the doc by tests/steering/test_steering_trips.py).
"""
from __future__ import annotations

from dataclasses import dataclass

from viena.common.samples.steering import TripCause

#: what the core does for every cause: the drive holds the wheel, then lets it go
HOLD = "quick stop, power off after `quickstop_hold_s`"
ARM = "a new arm"
SWEEP = "configure, sweep, then a new arm"


@dataclass(frozen=True)
class Trip:
    """One row: a cause, the setting that is its deadline (part.name, None: at once), what
    happens, what it takes to steer again, and the label the state's `trip` text begins with."""
    cause: TripCause
    deadline: str | None
    reaction: str
    rearm: str
    label: str

    def text(self, detail: str = "") -> str:
        """The `trip` text: the label, then the detail (with its own punctuation)."""
        return self.label + detail


TRIPS: tuple[Trip, ...] = (
    Trip(TripCause.WATCHDOG, "envelope.watchdog_s", HOLD, ARM, "watchdog"),
    Trip(TripCause.FEEDBACK_TIMEOUT, "controller.feedback_timeout_s", HOLD, ARM, "no feedback from the drive"),
    Trip(TripCause.NO_POSITION, None, HOLD, ARM, "no position from the drive"),
    Trip(TripCause.DRIVE_HEARTBEAT, "drive.drive_heartbeat_timeout_s", HOLD, ARM, "drive heartbeat lost"),
    Trip(TripCause.LIFE_GUARD, "drive.host_heartbeat_timeout_s",
         "the drive faults and stops by itself; then " + HOLD, "a new arm (it resets the fault)",
         "drive EMCY 0x8130"),
    Trip(TripCause.DRIVE_FAULT, None, HOLD, "a new arm (it resets the fault)", "drive EMCY"),
    Trip(TripCause.NOT_ENABLED, None, HOLD, ARM, "drive left operation enabled"),
    Trip(TripCause.ESTOP, None, HOLD, ARM, "estop"),
    Trip(TripCause.LINK_LOST, None, "nothing can be sent: the drive's life guard stops it",
         "reconnect (backoff `controller.reconnect_min_s`..`reconnect_max_s`), then " + ARM, "CAN link lost"),
    Trip(TripCause.DRIVE_REBOOTED, None, HOLD, SWEEP, "drive rebooted: calibration lost"),
    Trip(TripCause.DRIVE_SILENT, "controller.silent_drive_s", HOLD, SWEEP, "drive silent: calibration lost"),
    Trip(TripCause.NOT_OPERATIONAL, "drive.drive_heartbeat_period_s", HOLD + " (after 3 periods)", SWEEP,
         "drive not operational: calibration lost"),
    Trip(TripCause.CALIBRATION_LOST, None, HOLD, SWEEP, "calibration lost"),
    Trip(TripCause.SERVICE_STOPPING, None, HOLD + " (then the link closes)", "start the service", "service stopping"),
)

_BY_CAUSE = {row.cause: row for row in TRIPS}


def trip(cause: TripCause) -> Trip:
    return _BY_CAUSE[cause]


def trip_text(cause: TripCause, detail: str = "") -> str:
    return _BY_CAUSE[cause].text(detail)


def markdown_table() -> str:
    """The table in docs/steering.md#watchdog-and-trips, made from TRIPS."""
    lines = ["| cause (`trip_cause`) | deadline | reaction | to steer again | `trip` begins with |",
             "|---|---|---|---|---|"]
    for row in TRIPS:
        deadline = f"`{row.deadline}`" if row.deadline else "at once"
        lines.append(f"| `{row.cause.value}` | {deadline} | {row.reaction} | {row.rearm} | `{row.label}` |")
    return "\n".join(lines) + "\n"
