"""What the steering core is told about the drive, and what it asks the runner to do.

The core (`core.SteeringCore`) never touches the bus: each of its methods takes a
`DriveReading` and the time, and returns a list of these actions. The runner
(`controller.SteeringController`) carries them out:

- frames, sent at once and in order: `Command`, `SendTarget`, `Cycle`;
- blocking work on the drive, done by its worker thread, whose outcome it reports back to
  the core: `Connect`, `Configure`, `WriteLimits`;
- `Reply`: the answer to a request that had to wait (an arm waits for the drive's DS402
  steps).
"""
from __future__ import annotations

from dataclasses import dataclass

from viena.services.steering.model.calibration import Calibration
from viena.services.steering.model.drive import Feedback


@dataclass(frozen=True)
class DriveReading:
    """The drive as the host last heard it."""
    feedback: Feedback = Feedback()
    heartbeat_age_s: float = float("inf")      # since the drive's last heartbeat
    nmt_state: int | None = None               # the state that heartbeat announced


# -- frames -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Command:
    """Send this controlword now (the RPDO carries the current target with it)."""
    controlword: int


@dataclass(frozen=True)
class SendTarget:
    """Send this position target now, with a new controlword if one is given."""
    target_qc: int
    controlword: int | None = None


@dataclass(frozen=True)
class Cycle:
    """The control period's frames: host heartbeat when due, RPDO (new target if given), SYNC."""
    target_qc: int | None = None


# -- blocking work ------------------------------------------------------------------------
@dataclass(frozen=True)
class Connect:
    """(Re)open the CAN link; then `SteeringCore.connected`."""


@dataclass(frozen=True)
class Configure:
    """Configure the drive by SDO, limits off; then `SteeringCore.configured`."""


@dataclass(frozen=True)
class WriteLimits:
    """Write the calibrated software position limits; then `SteeringCore.limits_written`."""
    calibration: Calibration


# -- answers ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Reply:
    """The answer to the request the runner registered under `token`."""
    token: object
    answer: dict


FRAMES = (Command, SendTarget, Cycle)
JOBS = (Connect, Configure, WriteLimits)
Action = Command | SendTarget | Cycle | Connect | Configure | WriteLimits | Reply
