"""An offline drive: the simulated car's truth with IMU samples and GNSS fixes made from it.

For closed-loop tests and the benchmark, without processes or sockets: `SimCar` (the
kinematic bicycle model the whole simulation uses) steps once per IMU period, and each
sensor turns its truth into a sample dict in the agreed schema. Two sets of sensors:

- "twins" (default): the device twins' own models -- `RazorBoard` (the sensor models of
  docs/sensors.md#imu-sensor-models with the parked recordings' noise, through the IMU
  service's calibration and sample builder) and the NovAtel `TruthSolver` (the error
  sources of docs/sensors.md#gnss-error-budget as Gauss-Markov processes scaled to 1.8 m
  CEP, satellites and outages, through the GNSS service's BESTXYZ-to-fix code). What the
  car's processes see, minus the bytes.
- "white": independent white errors of the same sizes (1.5 m per axis, 0.05 m/s, the
  Razor's noise and quantisation). No filter can remove a slowly drifting GNSS error
  without another reference, so this set shows what the filter does remove.

What the estimator's benchmark also needs, each off by default: a steady speed on a road
that suits it (`at_speed`: the campus loop up to 6 m/s, an open oval beyond), hills
(`grade_pct`), outages on a schedule (`periodic_outages`), IMU stamps off the GNSS clock
(`imu_stamps_late_s`), a residual accelerometer bias, a position-only receiver
(`gnss_velocity=False`, as NMEA GGA), sigmas sent as ENU or horizontal/vertical instead of
ECEF (`sigma_form`), and a second receiver under the same sky (`second_antenna_m`).
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import pymap3d

from viena.common.rotation import quat_multiply
from viena.services.gnss.driver.gpstime import utc_to_gps
from viena.services.sim.model.car import CarParams, SimCar
from viena.services.sim.model.route import oval
from viena.services.sim.model.truth import Truth

G = 9.80665
T0_NS = 1_717_236_000_000_000_000           # 2024-06-01 10:00:00 UTC, a whole GPS second


@dataclass
class Drive:
    duration_s: float = 300.0
    seed: int = 1
    sensors: str = "twins"              # "twins" or "white"
    car: CarParams = field(default_factory=CarParams)
    imu_rate_hz: float = 82.5           # the Razor firmware's loop (measured on the car)
    gnss_rate_hz: float = 20.0          # BESTXYZ ONTIME 0.05
    lever_arm_m: tuple = (0.0, 1.0, 1.5)
    with_mag: bool = True
    outages: tuple = ()                 # (start_s, end_s): the receiver has no solution
    random_outages: bool = False        # the twin's own short outages (as in the 2016 drive)
    route: str = "campus"               # "campus" (the 40 m x 24 m loop) or "open" (ROUTES)
    grade_pct: float = 0.0              # hills: the road's grade swings +- this much ...
    grade_period_m: float = 300.0       # ... over this distance driven
    imu_stamps_late_s: float = 0.0      # IMU stamps = true time + this (a late adapter: > 0)
    accel_bias_mps2: tuple | None = None   # body axes; None: the sensor set's own
    gnss_velocity: bool = True          # False: a position-only receiver (NMEA GGA)
    sigma_form: str = "ecef"            # sigmas as "ecef" (ecef_sigma_m), "enu" or "hv"
    second_antenna_m: tuple | None = None  # a second receiver, gnss1, under the same sky (twins)
    gnss_errors: str = "standalone"     # the GNSS twin's error profile (errors.py): or "gauss_markov"
    imu_mount_zyx_deg: tuple = (0.0, 0.0, 0.0)   # the board turned in the car, nobody told (twins)
    imu_errors: str = "car"             # the Razor twin's errors (docs/sensors.md#imu-error-model) or "none"


#: Roads for the simulated car: the campus loop, and an open oval (200 m straights, 60 m
#: bends: 3.3 m/s^2 sideways at 14 m/s) for speeds the loop's 12 m bends do not allow.
ROUTES = {"campus": oval, "open": lambda: oval(straight_m=200.0, radius_m=60.0)}


def at_speed(speed_mps: float, **kw) -> Drive:
    """A drive at a steady speed after the usual 10 s parked: the campus loop up to 6 m/s,
    the open oval above, with pure pursuit looking further ahead as speed grows."""
    route = "campus" if speed_mps <= 6.0 else "open"
    car = CarParams(speed_min_mps=speed_mps, speed_max_mps=speed_mps,
                    lookahead_m=max(6.0, 1.5 * speed_mps))
    return Drive(route=route, car=car, **kw)


def periodic_outages(first_s: float, every_s: float, length_s: float, until_s: float) -> tuple:
    """(start_s, end_s) pairs: `length_s` without GNSS every `every_s` from `first_s`."""
    starts = np.arange(first_s, until_s - length_s + 1e-9, every_s)
    return tuple((float(a), float(a + length_s)) for a in starts)


class DriveSamples:
    """Iterate the drive's samples in acquisition-time order:
    ("imu", sample, Truth at the sample) and ("gnss", fix, true antenna ENU position).

    The car steps once per IMU period, so each IMU sample carries the car's acceleration and
    turn rate over exactly the interval since the previous one, as an integrating IMU would.
    GNSS epochs fall between steps; their truth is interpolated.
    """

    def __init__(self, drive: Drive | None = None):
        self.drive = d = drive or Drive()
        if d.route not in ROUTES:
            raise ValueError(f"route {d.route!r}: one of {sorted(ROUTES)}")
        if d.sigma_form not in ("ecef", "enu", "hv"):
            raise ValueError(f"sigma_form {d.sigma_form!r}: ecef, enu or hv")
        self.rng = np.random.default_rng(d.seed)
        self.car = SimCar(d.car, route=ROUTES[d.route](), start_time_ns=T0_NS)
        self.origin = self.car.origin
        self.hills = Hills(d.grade_pct / 100.0, d.grade_period_m) if d.grade_pct else None
        self._truth = self.car.truth()
        if d.sensors == "twins":
            self.sensors = TwinSensors(d, self.rng, self.truth)
        elif d.sensors == "white":
            self.sensors = WhiteSensors(d, self.rng, self.origin)
        else:
            raise ValueError(f"sensors {d.sensors!r}: twins or white")
        if d.second_antenna_m is not None and d.sensors != "twins":
            raise ValueError("a second receiver needs the twins' sensors (one sky for both)")

    def truth(self) -> Truth:
        """The car's truth now (on its hills, if any): what the GNSS twins read."""
        return self._truth

    def __iter__(self) -> Iterator[tuple[str, dict, object]]:
        d = self.drive
        imu_dt = 1.0 / d.imu_rate_hz
        gnss_ns = int(round(1e9 / d.gnss_rate_hz))
        offset_ns = int(round(d.imu_stamps_late_s * 1e9))
        recent: deque[Truth] = deque([self.car.truth()], maxlen=64)
        n_imu = n_gnss = 0
        while True:
            n_imu += 1
            if n_imu * imu_dt > d.duration_s:
                return
            truth = self.car.step(imu_dt)
            if self.hills is not None:
                truth = self.hills.lift(truth, recent[-1], imu_dt)
            self._truth = truth
            recent.append(truth)
            while T0_NS + (n_gnss + 1) * gnss_ns <= truth.t_ns:
                n_gnss += 1
                t_ns = T0_NS + n_gnss * gnss_ns
                fix = self._as_sent(self.sensors.gnss(t_ns, recent, n_gnss))
                yield "gnss", fix, _interpolate(recent, t_ns, d.lever_arm_m)[0]
                if d.second_antenna_m is not None:
                    fix = self._as_sent(self.sensors.gnss_second(t_ns, recent, n_gnss))
                    yield "gnss", fix, _interpolate(recent, t_ns, d.second_antenna_m)[0]
            sample = self.sensors.imu(truth, n_imu)
            if offset_ns:
                sample["t"] += offset_ns
            if d.accel_bias_mps2 is not None:
                sample["accel_mps2"] = [a + b for a, b in zip(sample["accel_mps2"], d.accel_bias_mps2)]
            yield "imu", sample, truth

    def _as_sent(self, fix: dict) -> dict:
        """The fix as the drive's receiver sends it: without a velocity for a position-only
        receiver, sigmas in the drive's form (ENU or horizontal/vertical: no ECEF sigmas)."""
        d = self.drive
        if not d.gnss_velocity:
            fix.update(vel_ecef_mps=None, vel_sigma_mps=None, vel_status="INSUFFICIENT_OBS",
                       vel_type="NONE", vel_latency_s=0.0)
        if d.sigma_form != "ecef" and fix["valid"]:
            e, n, u = self.sensors.sigma_enu(fix["unit"])
            del fix["ecef_sigma_m"]
            if d.sigma_form == "enu":
                fix["enu_sigma_m"] = [e, n, u]
            else:
                fix["sigma_h_m"], fix["sigma_v_m"] = math.sqrt(0.5 * (e * e + n * n)), u
        return fix


class Hills:
    """The road goes up and down as the car drives: grade G sin(2 pi s / L) over the
    distance s driven, so height h(s) = G L / (2 pi) (1 - cos(2 pi s / L)).

    The flat car's truth is lifted onto it exactly: the horizontal motion is the car's,
    the height, vertical velocity (v h') and acceleration (a h' + v^2 h'') follow, the
    car pitches nose up by atan(h') about its right axis, and the gyro feels the pitch rate
    and the yaw rate turned by the pitch (body rate [theta', psi' sin theta, psi' cos theta])."""

    def __init__(self, grade: float, period_m: float):
        self.grade, self.k = grade, 2.0 * math.pi / period_m
        self.s = 0.0

    def lift(self, truth: Truth, previous: Truth, dt: float) -> Truth:
        v = truth.speed_mps
        self.s += 0.5 * (previous.speed_mps + v) * dt
        g, k, s = self.grade, self.k, self.s
        slope = g * math.sin(k * s)                          # h'
        curve = g * k * math.cos(k * s)                      # h''
        height = g / k * (1.0 - math.cos(k * s))
        yaw_rate = float(truth.gyro_body_radps[2])
        fwd = truth.vel_enu_mps / v if v > 0.0 else truth.rot[:, 1]
        along = float(truth.accel_enu_mps2 @ fwd)
        pitch = math.atan(slope)
        pitch_rate = v * curve / (1.0 + slope * slope)
        half = 0.5 * pitch
        quat = quat_multiply(truth.quat, (math.cos(half), math.sin(half), 0.0, 0.0))
        return Truth(
            t_ns=truth.t_ns, t_s=truth.t_s, origin=truth.origin,
            enu_m=truth.enu_m + np.array([0.0, 0.0, height]),
            vel_enu_mps=truth.vel_enu_mps + np.array([0.0, 0.0, v * slope]),
            accel_enu_mps2=truth.accel_enu_mps2 + np.array([0.0, 0.0, along * slope + v * v * curve]),
            quat=np.asarray(quat, float),
            gyro_body_radps=np.array([pitch_rate, yaw_rate * math.sin(pitch), yaw_rate * math.cos(pitch)]),
            speed_mps=v, wheel_angle_rad=truth.wheel_angle_rad, gravity_mps2=truth.gravity_mps2,
            seq=truth.seq)


class TwinSensors:
    """The IMU and GNSS twins' error models, through the services' own sample code."""

    def __init__(self, drive: Drive, rng, truth_fn):
        from viena.services.gnss.driver.novatel.enums import MessageId, TimeStatus
        from viena.services.gnss.driver.novatel.framing import Header
        from viena.services.gnss.driver.novatel.logs import LogMessage
        from viena.services.gnss.fixes import fix_from_bestxyz
        from viena.services.gnss.simulator.errors import GnssErrorModel, SkyModel
        from viena.services.gnss.simulator.novatel_logs import bestxyz_of
        from viena.services.gnss.simulator.solution import TruthSolver
        from viena.services.imu.driver import Frame, Reading
        from viena.services.imu.model.calibration import SampleCalibrator, seed_calibration
        from viena.services.imu.model.sample_builder import SampleBuilder
        from viena.services.imu.simulator import CAR_RAZOR_ERRORS, NO_ERRORS, RazorBoard

        self.drive, self.rng = drive, rng
        errors = CAR_RAZOR_ERRORS if drive.imu_errors == "car" else NO_ERRORS
        self.board = RazorBoard(mount_zyx_deg=tuple(drive.imu_mount_zyx_deg), errors=errors)
        self.builder = SampleBuilder("imu0", "viena", SampleCalibrator(seed_calibration("viena")))
        self._frame, self._reading = Frame, Reading
        from viena.services.gnss.simulator.errors import CommonErrors

        def sky():
            return SkyModel(rng, outages=tuple((a, b) for a, b in drive.outages),
                            outage_interval_s=64.0 if drive.random_outages else 0.0)
        common = CommonErrors(rng) if drive.second_antenna_m is not None else None
        profile = drive.gnss_errors
        self.solver = TruthSolver(truth_fn, drive.lever_arm_m,
                                  errors=GnssErrorModel(rng, common=common, profile=profile), sky=sky())
        self.second = None
        if drive.second_antenna_m is not None:
            self.second = TruthSolver(truth_fn, drive.second_antenna_m,
                                      errors=GnssErrorModel(rng, common=common, profile=profile), sky=sky())
        self._header, self._log, self._fix, self._bestxyz = Header, LogMessage, fix_from_bestxyz, bestxyz_of
        self._ids = (MessageId.BESTXYZ, TimeStatus.FINESTEERING)

    def imu(self, truth: Truth, seq: int) -> dict:
        m = self.board.measure(truth, self.rng)
        frame = self._frame(self.board.board_id, m.accel_g, m.gyro_dps, m.mag_counts, m.euler_deg)
        sample = self.builder.build(self._reading(truth.t_ns, truth.t_ns, seq, frame))
        if not self.drive.with_mag:
            sample["mag_T"] = None
        return sample

    def gnss(self, t_ns: int, recent, seq: int) -> dict:
        week, ms = utc_to_gps(t_ns)
        solution = self.solver.solve(week * 604_800_000 + ms, t_ns)
        header = self._header(self._ids[0], week=week, milliseconds=ms, time_status=self._ids[1])
        # the twin's velocity is as old as the Doppler latency it reports, like the OEM4's
        return self._fix(self._log(header, self._bestxyz(solution), t_ns + 50_000_000), "gnss0", seq)

    def gnss_second(self, t_ns: int, recent, seq: int) -> dict:
        """The same epoch from the second receiver, gnss1 (its own antenna, the same sky)."""
        first = self.solver
        self.solver = self.second
        try:
            return dict(self.gnss(t_ns, recent, seq), unit="gnss1")
        finally:
            self.solver = first

    def sigma_enu(self, unit: str) -> tuple:
        """The receiver's position sigmas along E, N, U (what BESTPOS or GST would send)."""
        solver = self.second if unit == "gnss1" else self.solver
        return tuple(float(v) for v in solver.errors.sigma_enu)


class WhiteSensors:
    """White errors of the twins' sizes (docs/sensors.md#gnss-error-budget,
    docs/sensors.md#imu-sensor-models), independent from sample to sample."""

    accel_sigma = 0.006 * G
    accel_bias_sigma = 0.003 * G
    accel_lsb = 0.0039 * G
    gyro_sigma = math.radians(0.035)
    gyro_bias_sigma = math.radians(0.03)
    gyro_lsb = math.radians(1 / 14.375)
    mag_sigma_T = 0.3e-6
    pos_sigma_m = 1.5                   # per ECEF axis: 1.8 m CEP
    vel_sigma_mps = 0.05
    vel_latency_s = 0.025

    def __init__(self, drive: Drive, rng, origin):
        self.drive, self.rng, self.origin = drive, rng, origin
        self.accel_bias = rng.normal(0.0, self.accel_bias_sigma, 3)
        self.gyro_bias = rng.normal(0.0, self.gyro_bias_sigma, 3)

    def imu(self, truth: Truth, seq: int) -> dict:
        rng = self.rng
        acc = truth.specific_force_body_mps2 + self.accel_bias + rng.normal(0.0, self.accel_sigma, 3)
        acc = np.round(acc / self.accel_lsb) * self.accel_lsb
        gyr = truth.gyro_body_radps + self.gyro_bias + rng.normal(0.0, self.gyro_sigma, 3)
        gyr = np.round(gyr / self.gyro_lsb) * self.gyro_lsb
        mag = None
        if self.drive.with_mag:
            mag = [float(v) for v in truth.mag_body_T() + rng.normal(0.0, self.mag_sigma_T, 3)]
        return {
            "t": truth.t_ns, "seq": seq, "unit": "imu0", "firmware": "viena",
            "accel_mps2": [float(v) for v in acc], "gyro_radps": [float(v) for v in gyr],
            "mag_T": mag,
            "raw": {"accel_g": [float(v) / G for v in acc],
                    "gyro_dps": [math.degrees(v) for v in gyr],
                    "mag_counts": [0.0, 0.0, 0.0], "euler_deg": None},
            "board_id": 1,
        }

    def gnss(self, t_ns: int, recent, seq: int) -> dict:
        week, ms = utc_to_gps(t_ns)
        arm = self.drive.lever_arm_m
        fix = {
            "t": t_ns, "seq": seq, "unit": "gnss0", "protocol": "novatel",
            "gps_week": week, "gps_ms": ms, "t_host": t_ns + 50_000_000, "latency_s": 0.05,
            "vel_latency_s": self.vel_latency_s, "diff_age_s": 0.0, "sol_age_s": 0.0,
            "sats_tracked": 9, "sats_used": 8,
        }
        t_s = (t_ns - T0_NS) * 1e-9
        if any(a <= t_s < b for a, b in self.drive.outages):
            fix.update(valid=False, pos_status="INSUFFICIENT_OBS", pos_type="NONE",
                       vel_status="INSUFFICIENT_OBS", vel_type="NONE",
                       ecef_m=[100.0, 0.0, 0.0], ecef_sigma_m=[0.0, 0.0, 0.0],
                       vel_ecef_mps=[0.0, 0.0, 0.0], vel_sigma_mps=[0.0, 0.0, 0.0],
                       lat_deg=0.0, lon_deg=0.0, height_m=0.0, sats_used=0)
            return fix
        pos, _ = _interpolate(recent, t_ns, arm)
        _, vel = _interpolate(recent, t_ns - int(self.vel_latency_s * 1e9), arm)
        lat0, lon0, h0 = self.origin
        ecef = np.array(pymap3d.enu2ecef(*pos, lat0, lon0, h0), float)
        ecef += self.rng.normal(0.0, self.pos_sigma_m, 3)
        v = np.array(pymap3d.enu2uvw(*vel, lat0, lon0), float) + self.rng.normal(0.0, self.vel_sigma_mps, 3)
        lat, lon, h = pymap3d.ecef2geodetic(*ecef)
        fix.update(valid=True, pos_status="SOL_COMPUTED", pos_type="SINGLE",
                   vel_status="SOL_COMPUTED", vel_type="DOPPLER_VELOCITY",
                   ecef_m=[float(x) for x in ecef], ecef_sigma_m=[self.pos_sigma_m] * 3,
                   vel_ecef_mps=[float(x) for x in v], vel_sigma_mps=[self.vel_sigma_mps] * 3,
                   lat_deg=float(lat), lon_deg=float(lon), height_m=float(h))
        return fix

    def sigma_enu(self, unit: str) -> tuple:
        """Isotropic: the same sigma along E, N, U as along the ECEF axes."""
        return (self.pos_sigma_m,) * 3


def _interpolate(recent, t_ns: int, arm) -> tuple[np.ndarray, np.ndarray]:
    """ENU position and velocity of a body point at t_ns, between the two nearest steps."""
    later = None
    for truth in reversed(recent):
        if truth.t_ns <= t_ns:
            earlier = truth
            break
        later = truth
    else:
        raise ValueError(f"no truth as old as {t_ns} ns")
    if later is None:
        return earlier.enu_of(arm), earlier.vel_enu_of(arm)
    f = (t_ns - earlier.t_ns) / (later.t_ns - earlier.t_ns)
    return ((1 - f) * earlier.enu_of(arm) + f * later.enu_of(arm),
            (1 - f) * earlier.vel_enu_of(arm) + f * later.vel_enu_of(arm))
