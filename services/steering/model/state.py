"""The steering state sample (common/samples/steering.py), read off the core."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from viena.common.samples.steering import TripCause

if TYPE_CHECKING:                     # the schema alone must not pull in the CAN stack
    from viena.services.steering.model.actions import DriveReading
    from viena.services.steering.model.core import SteeringCore


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
