"""Ground truth of the simulated car: the one picture every device twin turns into bytes.

Conventions (docs/frames.md): world is local ENU (x East, y North, z Up) at a geodetic origin;
body is x right, y forward, z up, so at yaw 0 the car points North; yaw is positive
counter-clockwise seen from above (a left turn), compass heading = -yaw.
Quaternions are Hamilton, scalar first, rotating body vectors into ENU.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from viena.common import rotation
from viena.common.geodesy import LocalFrame

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
    # the vectors as tuples of floats, for a Truth made by of_floats (None: made by the constructor)
    _floats: ClassVar[dict[str, tuple] | None] = None

    @classmethod
    def of_floats(cls, *, t_ns: int, t_s: float, origin: tuple, enu_m: tuple, vel_enu_mps: tuple,
                  accel_enu_mps2: tuple, quat: tuple, gyro_body_radps: tuple, speed_mps: float,
                  wheel_angle_rad: float, gravity_mps2: float = 9.80665, seq: int = 0) -> Truth:
        """A Truth whose vectors are given as tuples of floats: each becomes its numpy array only
        when read (VECTORS). The simulated car makes 100 a second, and its readers mostly want
        the floats (`floats`): five small arrays were most of the cost of making one."""
        truth = object.__new__(cls)
        truth.__dict__.update(t_ns=t_ns, t_s=t_s, origin=origin, speed_mps=speed_mps,
                              wheel_angle_rad=wheel_angle_rad, gravity_mps2=gravity_mps2, seq=seq,
                              _floats={"enu_m": enu_m, "vel_enu_mps": vel_enu_mps, "accel_enu_mps2": accel_enu_mps2,
                                       "quat": quat, "gyro_body_radps": gyro_body_radps})
        return truth

    def floats(self, name: str) -> tuple:
        """The vector field `name` (one of VECTORS) as a tuple of Python floats."""
        made = self._floats
        if made is not None:
            return made[name]
        return tuple(np.asarray(getattr(self, name), float).tolist())

    @property
    def unit_quat(self) -> list[float] | np.ndarray:
        """quat / |quat| as floats (rotation.unit_quat: the bits quat_to_matrix works from)."""
        unit = self._unit_quat
        if unit is None:
            made = self._floats
            unit = rotation.unit_quat(self.quat if made is None else made["quat"])
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
            ax, ay, az = self.floats("accel_enu_mps2")
            f_enu = np.array([ax + 0.0, ay + 0.0, az + self.gravity_mps2])   # + 0.0 as numpy's sum: -0.0 -> 0.0
            force = self.rot.T.dot(f_enu)
            force.flags.writeable = False
            object.__setattr__(self, "_specific_force", force)
        return force

    def enu_of(self, lever_arm_body_m) -> np.ndarray:
        """ENU position of a point fixed to the body (an antenna, say)."""
        return np.array(self._plus_rotated(self.floats("enu_m"), np.asarray(lever_arm_body_m, float)))

    def vel_enu_of(self, lever_arm_body_m) -> np.ndarray:
        """ENU velocity of a point fixed to the body: v + R (w x r)."""
        return np.array(self.vel_enu_floats_of(lever_arm_body_m))

    def vel_enu_floats_of(self, lever_arm_body_m) -> list[float]:
        """vel_enu_of as floats. The cross product in Python floats: np.cross costs tens of
        microseconds on 3-vectors, and the drives call this tens of thousands of times (same
        arithmetic, same bits)."""
        rx, ry, rz = np.asarray(lever_arm_body_m, float).tolist()
        wx, wy, wz = self.floats("gyro_body_radps")
        w_cross_r = np.array([wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx])
        return self._plus_rotated(self.floats("vel_enu_mps"), w_cross_r)

    def _plus_rotated(self, vector_enu: tuple, body: np.ndarray) -> list[float]:
        """vector + R body, the sum element by element in floats as numpy's (the same bits)."""
        return [v + d for v, d in zip(vector_enu, self.rot.dot(body).tolist())]

    @property
    def frame(self) -> LocalFrame:
        """The local ENU frame at the origin."""
        return _local_frame(self.origin)

    def enu_floats_of(self, lever_arm_body_m=BODY_ORIGIN) -> list[float]:
        """enu_of as floats; the body origin's without the rotation (R 0 adds nothing)."""
        if lever_arm_body_m is BODY_ORIGIN:
            return list(self.floats("enu_m"))
        return self._plus_rotated(self.floats("enu_m"), np.asarray(lever_arm_body_m, float))

    def geodetic_of(self, lever_arm_body_m=BODY_ORIGIN) -> tuple[float, float, float]:
        return self.frame.geodetic_of_enu(*self.enu_floats_of(lever_arm_body_m))

    def ecef_of(self, lever_arm_body_m=BODY_ORIGIN) -> np.ndarray:
        return np.array(self.ecef_floats_of(lever_arm_body_m), float)

    def ecef_floats_of(self, lever_arm_body_m=BODY_ORIGIN) -> tuple[float, float, float]:
        """ecef_of as floats (pymap3d.enu2ecef's numbers, LocalFrame.ecef_of_enu)."""
        return self.frame.ecef_of_enu(*self.enu_floats_of(lever_arm_body_m))

    def vel_ecef_of(self, lever_arm_body_m=BODY_ORIGIN) -> np.ndarray:
        e, n, u = self.vel_enu_floats_of(lever_arm_body_m)
        return np.array(self.frame.vector_of_enu(e, n, u), float)

    def mag_body_T(self, field_enu_nT=LISBON_MAG_ENU_NT) -> np.ndarray:
        """The Earth's magnetic field in body axes, tesla."""
        field_T = _LISBON_MAG_ENU_T if field_enu_nT is LISBON_MAG_ENU_NT else np.asarray(field_enu_nT, float) * 1e-9
        return self.body_of_enu(field_T)

    def body_of_enu(self, vector_enu: np.ndarray) -> np.ndarray:
        """A vector given in ENU (a float array), in body axes."""
        return self.rot.T.dot(vector_enu)

    @property
    def yaw_rad(self) -> float:
        return float(np.arctan2(self.rot[1, 0], self.rot[0, 0]))


class _ArrayOnRead:
    """A vector field of a Truth made by Truth.of_floats: its array, made on first read and then
    kept in the Truth (read-only: `floats` keeps answering the same numbers). A non-data
    descriptor, so a value the constructor set comes first."""

    def __init__(self, name: str):
        self.name = name

    def __get__(self, truth: Truth | None, owner: Any = None) -> Any:
        if truth is None:
            return self
        array = truth.__dict__[self.name] = np.array(truth.floats(self.name))
        array.flags.writeable = False
        return array


#: the fields of a Truth that are numpy 3-vectors (the quaternion a 4-vector)
VECTORS = ("enu_m", "vel_enu_mps", "accel_enu_mps2", "quat", "gyro_body_radps")
for _name in VECTORS:
    setattr(Truth, _name, _ArrayOnRead(_name))
#: the default field in tesla (np.asarray(field, float) * 1e-9, once)
_LISBON_MAG_ENU_T = LISBON_MAG_ENU_NT * 1e-9
LISBON_MAG_ENU_NT.flags.writeable = False
_LISBON_MAG_ENU_T.flags.writeable = False

_FRAMES: dict[tuple, LocalFrame] = {}


def _local_frame(origin) -> LocalFrame:
    key = tuple(origin)
    if key not in _FRAMES:
        _FRAMES[key] = LocalFrame(*key)
    return _FRAMES[key]


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
        "enu_m": list(truth.floats("enu_m")),
        "vel_enu_mps": list(truth.floats("vel_enu_mps")),
        "accel_enu_mps2": list(truth.floats("accel_enu_mps2")),
        "quat": list(truth.floats("quat")),
        "euler_rad": list(truth.euler_rad),
        "gyro_radps": list(truth.floats("gyro_body_radps")),
        "specific_force_mps2": truth.specific_force_body_mps2.tolist(),
        "speed_mps": float(truth.speed_mps),
        "wheel_angle_rad": float(truth.wheel_angle_rad),
    }
