"""viena.sim.truth/1 on viena/<car>/sim/truth (100 Hz): the simulated car's ground truth as
it crosses a process, and its monitor view. The truth itself (the dataclass every twin reads)
and `truth_sample`, which makes this sample of it, are the sim's: services/sim/model/truth.py."""
from __future__ import annotations

from viena.common.display import fmt_deg, fmt_unit, fmt_vec, vector
from viena.common.schema import F, Schema

TRUTH = Schema("viena.sim.truth/1", {
    "t": F.time,
    "seq": F.int,
    "t_sim_s": F.float,
    "origin": F.vec(3),                 # ENU origin: lat_deg, lon_deg, height_m
    "ecef_m": F.vec(3),
    "lat_deg": F.float,
    "lon_deg": F.float,
    "height_m": F.float,
    "enu_m": F.vec(3),
    "vel_enu_mps": F.vec(3),
    "accel_enu_mps2": F.vec(3),
    "quat": F.vec(4),                   # body -> ENU, Hamilton [w x y z]
    "euler_rad": F.vec(3),              # yaw, pitch, roll (Z-Y-X)
    "gyro_radps": F.vec(3),             # body angular rate
    "specific_force_mps2": F.vec(3),    # body, what an accelerometer feels
    "speed_mps": F.float,
    "wheel_angle_rad": F.float,
})


def monitor_view(sample: dict) -> dict[str, str]:
    """How the monitor shows the simulated car's truth (any map: what came on its key)."""
    euler = vector(sample.get("euler_rad"), 3)
    return {
        "position ENU m": fmt_vec(sample.get("enu_m")),
        "speed": fmt_unit(sample.get("speed_mps"), "m/s"),
        "yaw": "-" if euler is None else fmt_deg(euler[0]),
        "wheel": fmt_deg(sample.get("wheel_angle_rad")),
    }
