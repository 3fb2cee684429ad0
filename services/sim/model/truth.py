"""Ground truth of the simulated car: the one picture every device twin turns into bytes.

Conventions (docs/frames.md): world is local ENU (x East, y North, z Up) at a geodetic origin;
body is x right, y forward, z up, so at yaw 0 the car points North; yaw is positive
counter-clockwise seen from above (a left turn), compass heading = -yaw.
Quaternions are Hamilton, scalar first, rotating body vectors into ENU.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from viena.common import rotation
from viena.common.display import fmt_deg, fmt_unit, fmt_vec, vector
from viena.common.geodesy import LocalFrame
from viena.common.schema import F, Schema

#: Lisbon geomagnetic field, Jan 2017 (docs/frames.md#magnetic-field-in-lisbon), nT in ENU.
LISBON_MAG_ENU_NT = np.array([-1121.5, 26479.8, -34884.7])
LISBON_DECLINATION_DEG = 2.48
LISBON_INCLINATION_DEG = 52.77
#: IST campus, Lisbon: the simulated car's default ENU origin.
IST_ORIGIN = (38.7369, -9.1395, 100.0)
#: the body frame's origin (rear axle centre) as a lever arm: where a Truth's own position is
BODY_ORIGIN = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Truth:
    """The car's true state at one instant."""

    t_ns: int                      # absolute time, ns UTC
    t_s: float                     # simulation time since start, s
    origin: tuple                  # (lat_deg, lon_deg, height_m) of the ENU origin
    enu_m: np.ndarray              # position of the body origin (rear axle centre), ENU
    vel_enu_mps: np.ndarray
    accel_enu_mps2: np.ndarray
    quat: np.ndarray               # body -> ENU, [w, x, y, z]
    gyro_body_radps: np.ndarray    # angular rate of body w.r.t. ENU, in body axes
    speed_mps: float
    wheel_angle_rad: float         # bicycle-model front wheel angle, positive = left
    gravity_mps2: float = 9.80665
    seq: int = 0
    # worked out once per instant, on first use: the sim's loop, the IMU twin and both GNSS
    # twins all read the same Truth object of an instant. Class attributes, not fields: the
    # constructor does not pay for them, and dataclasses.replace starts a new Truth afresh
    _unit_quat: ClassVar[list[float] | np.ndarray | None] = None
    _rot: ClassVar[np.ndarray | None] = None
    _specific_force: ClassVar[np.ndarray | None] = None

    @property
    def unit_quat(self) -> list[float] | np.ndarray:
        """quat / |quat| as floats (rotation.unit_quat: the bits quat_to_matrix works from)."""
        unit = self._unit_quat
        if unit is None:
            unit = rotation.unit_quat(self.quat)
            object.__setattr__(self, "_unit_quat", unit)
        return unit

    @property
    def rot(self) -> np.ndarray:
        """Rotation matrix body -> ENU. (Its products here are `dot`s: the same BLAS call as `@`,
        so the same bits, at half the cost on 3-vectors.)"""
        rot = self._rot
        if rot is None:
            rot = rotation.unit_quat_to_matrix(*self.unit_quat)
            object.__setattr__(self, "_rot", rot)
        return rot

    @property
    def euler_rad(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll), as euler_from_quat(quat)."""
        return rotation.euler_from_unit_quat(*self.unit_quat)

    @property
    def specific_force_body_mps2(self) -> np.ndarray:
        """What an ideal accelerometer feels: a - g, in body axes (at rest: +g on z). Read-only."""
        force = self._specific_force
        if force is None:
            ax, ay, az = np.asarray(self.accel_enu_mps2, float).tolist()
            f_enu = np.array([ax + 0.0, ay + 0.0, az + self.gravity_mps2])   # + 0.0 as numpy's sum: -0.0 -> 0.0
            force = self.rot.T.dot(f_enu)
            force.flags.writeable = False
            object.__setattr__(self, "_specific_force", force)
        return force

    def enu_of(self, lever_arm_body_m) -> np.ndarray:
        """ENU position of a point fixed to the body (an antenna, say)."""
        return self.enu_m + self.rot.dot(np.asarray(lever_arm_body_m, float))

    def vel_enu_of(self, lever_arm_body_m) -> np.ndarray:
        """ENU velocity of a point fixed to the body: v + R (w x r).

        The cross product in Python floats: np.cross costs tens of microseconds on 3-vectors, and the
        drives call this tens of thousands of times (same arithmetic, same bits)."""
        rx, ry, rz = np.asarray(lever_arm_body_m, float).tolist()
        wx, wy, wz = np.asarray(self.gyro_body_radps, float).tolist()
        w_cross_r = np.array([wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx])
        return self.vel_enu_mps + self.rot.dot(w_cross_r)

    @property
    def frame(self) -> LocalFrame:
        """The local ENU frame at the origin."""
        return _local_frame(self.origin)

    def _enu_floats_of(self, lever_arm_body_m) -> list[float]:
        """enu_of as floats; the body origin's without the rotation (R 0 adds nothing)."""
        if lever_arm_body_m is BODY_ORIGIN:
            return np.asarray(self.enu_m, float).tolist()
        return self.enu_of(lever_arm_body_m).tolist()

    def geodetic_of(self, lever_arm_body_m=BODY_ORIGIN) -> tuple[float, float, float]:
        return self.frame.geodetic_of_enu(*self._enu_floats_of(lever_arm_body_m))

    def ecef_of(self, lever_arm_body_m=BODY_ORIGIN) -> np.ndarray:
        return np.array(self.ecef_floats_of(lever_arm_body_m), float)

    def ecef_floats_of(self, lever_arm_body_m=BODY_ORIGIN) -> tuple[float, float, float]:
        """ecef_of as floats (pymap3d.enu2ecef's numbers, LocalFrame.ecef_of_enu)."""
        return self.frame.ecef_of_enu(*self._enu_floats_of(lever_arm_body_m))

    def vel_ecef_of(self, lever_arm_body_m=BODY_ORIGIN) -> np.ndarray:
        e, n, u = self.vel_enu_of(lever_arm_body_m).tolist()
        return np.array(self.frame.vector_of_enu(e, n, u), float)

    def mag_body_T(self, field_enu_nT=LISBON_MAG_ENU_NT) -> np.ndarray:
        """The Earth's magnetic field in body axes, tesla."""
        return self.rot.T.dot(np.asarray(field_enu_nT, float) * 1e-9)

    @property
    def yaw_rad(self) -> float:
        return float(np.arctan2(self.rot[1, 0], self.rot[0, 0]))


_FRAMES: dict[tuple, LocalFrame] = {}


def _local_frame(origin) -> LocalFrame:
    key = tuple(origin)
    if key not in _FRAMES:
        _FRAMES[key] = LocalFrame(*key)
    return _FRAMES[key]


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


def truth_sample(truth: Truth) -> dict:
    """The published form of a Truth (plain lists of floats, float64 ECEF)."""
    lat, lon, h = truth.geodetic_of()
    return {
        "t": truth.t_ns,
        "seq": truth.seq,
        "t_sim_s": truth.t_s,
        "origin": [float(v) for v in truth.origin],
        "ecef_m": list(truth.ecef_floats_of()),
        "lat_deg": lat,
        "lon_deg": lon,
        "height_m": h,
        "enu_m": truth.enu_m.tolist(),
        "vel_enu_mps": truth.vel_enu_mps.tolist(),
        "accel_enu_mps2": truth.accel_enu_mps2.tolist(),
        "quat": truth.quat.tolist(),
        "euler_rad": list(truth.euler_rad),
        "gyro_radps": truth.gyro_body_radps.tolist(),
        "specific_force_mps2": truth.specific_force_body_mps2.tolist(),
        "speed_mps": float(truth.speed_mps),
        "wheel_angle_rad": float(truth.wheel_angle_rad),
    }


def monitor_view(sample: dict) -> dict[str, str]:
    """How the monitor shows the simulated car's truth (any map: what came on its key)."""
    euler = vector(sample.get("euler_rad"), 3)
    return {
        "position ENU m": fmt_vec(sample.get("enu_m")),
        "speed": fmt_unit(sample.get("speed_mps"), "m/s"),
        "yaw": "-" if euler is None else fmt_deg(euler[0]),
        "wheel": fmt_deg(sample.get("wheel_angle_rad")),
    }
