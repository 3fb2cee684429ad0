"""Helpers for the laptop tools' tests: the sim car as a process, the CLI, and a drive
recording made offline from the simulated car (no processes, deterministic)."""
from __future__ import annotations

import math
import queue
from pathlib import Path

import msgpack
import numpy as np
from vienatest import VIENA, viena  # noqa: F401  (the laptop tests import them from here)

from viena.common.recording import RecordingWriter

TRUTH_KEY = "viena/elettra/sim/truth"
SIM_HEALTH_KEY = "viena/elettra/sim/health"
FIX_ENCODING = "application/msgpack;viena.gnss.fix/1"
STATE_ENCODING = "application/msgpack;viena.estimator.state/2"
STEERING_ENCODING = "application/msgpack;viena.steering.state/1"
TRUTH_ENCODING = "application/msgpack;viena.sim.truth/1"


def start_sim(procs, router: str, tmp_path: Path, parked_s: float = 10.0):
    """The simulated car as a process, publishing truth at 100 Hz and health at 1 Hz."""
    config = tmp_path / "sim.toml"
    config.write_text(f"[sim]\nparked_s = {parked_s}\n")
    return procs.python("-m", "viena.services.sim.service", "--connect", router,
                        "--config", config, "--log-level", "WARNING")


def wait_for_samples(session, keyexpr: str, timeout: float = 20.0) -> None:
    """Block until a sample arrives on keyexpr (the process behind it is up)."""
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(keyexpr, lambda s: got.put(1))
    try:
        got.get(timeout=timeout)
    finally:
        sub.undeclare()



def write_drive(path: Path, seconds: float = 20.0, seed: int = 3) -> dict:
    """A drive recorded as viena record would have written it, made offline from the
    simulated car: truth at 100 Hz, a GNSS fix at 10 Hz (some without a solution), an
    estimator state and a steering state at 20 Hz. Returns what was written, by key."""
    from viena.services.sim.model.car import CarParams, SimCar
    from viena.services.sim.model.truth import truth_sample

    rng = np.random.default_rng(seed)
    car = SimCar(CarParams(parked_s=1.0), start_time_ns=1_717_236_000_000_000_000)
    writer = RecordingWriter(path)
    written: dict[str, list] = {}

    def write(key, encoding, sample, t):
        writer.write(key, encoding, t + 2_000_000, msgpack.packb(sample))
        written.setdefault(key, []).append(sample)

    for step in range(int(seconds * 100)):
        truth = car.step(0.01)
        t = truth.t_ns
        write(TRUTH_KEY, TRUTH_ENCODING, truth_sample(truth), t)
        if step % 10 == 0:
            write("viena/elettra/gnss/gnss0/fix", FIX_ENCODING, _fix(truth, rng, step // 10), t)
        if step % 5 == 0:
            write("viena/elettra/estimator/state", STATE_ENCODING, _state(truth, rng, step // 5), t)
            write("viena/elettra/steering/state", STEERING_ENCODING, _steering(truth, step // 5), t)
    writer.close()
    return written


def _fix(truth, rng, seq: int) -> dict:
    import pymap3d

    lever = (0.0, 1.0, 1.5)
    no_solution = seq % 25 == 24
    ecef = [100.0, 0.0, 0.0] if no_solution else (truth.ecef_of(lever) + rng.normal(0, 1.0, 3)).tolist()
    lat, lon, h = pymap3d.ecef2geodetic(*ecef)
    return {"t": truth.t_ns, "seq": seq, "unit": "gnss0", "protocol": "novatel",
            "valid": not no_solution,
            "pos_status": "INSUFFICIENT_OBS" if no_solution else "SOL_COMPUTED",
            "pos_type": "NONE" if no_solution else "SINGLE", "vel_status": "SOL_COMPUTED",
            "vel_type": "DOPPLER_VELOCITY", "ecef_m": ecef, "ecef_sigma_m": [1.0, 1.0, 1.0],
            "vel_ecef_mps": truth.vel_ecef_of(lever).tolist(), "vel_sigma_mps": [0.05] * 3,
            "lat_deg": float(lat), "lon_deg": float(lon), "height_m": float(h),
            "sats_tracked": 9, "sats_used": 0 if no_solution else 8, "gps_week": 2317,
            "gps_ms": 1000 * seq, "t_host": truth.t_ns + 50_000_000, "latency_s": 0.05,
            "vel_latency_s": 0.025, "diff_age_s": None, "sol_age_s": 0.0}


def _steering(truth, seq: int) -> dict:
    """Shaped like viena.steering.state/1 (services/steering/model/state.py): angles in degrees."""
    angle = math.degrees(truth.wheel_angle_rad)
    return {"t": truth.t_ns, "seq": seq, "phase": "armed", "armed": True, "owner": "3f2a9c1b7d4e",
            "angle_deg": angle, "angle_qc": int(angle * 1000), "target_deg": angle + 0.5,
            "target_qc": int((angle + 0.5) * 1000), "goal_deg": angle + 1.0,
            "ds402": "OPERATION_ENABLED", "statusword": 0x0437, "following_error_qc": 12,
            "drive_heartbeat": "ok", "watchdog": "ok", "trip": "", "fault": "", "emcy": "",
            "limits": [], "decision": {"status": "accepted", "reason": ""},
            "calibration": {"state": "done", "range_deg": 58.0}}


def _state(truth, rng, seq: int) -> dict:
    enu = (truth.enu_m + rng.normal(0, 0.2, 3)).tolist()
    return {"t": truth.t_ns, "seq": seq, "mode": "navigating", "aligned": True,
            "heading_valid": True, "heading_source": "course", "position_valid": True,
            "imu_live": True, "gnss_live": ["gnss0"], "origin": list(truth.origin),
            "origin_source": "config", "enu_m": enu, "enu_var_m2": [0.04, 0.04, 0.09],
            "enu_cov_m2": [0.04, 0.0, 0.0, 0.04, 0.0, 0.09], "enu_sigma_m": [0.2, 0.2, 0.3],
            "sigma_h_m": 0.2, "sigma_v_m": 0.3, "standstill": False, "imu_time_offset_hint_s": None,
            "vel_enu_mps": truth.vel_enu_mps.tolist(), "vel_var_m2ps2": [0.01] * 3,
            "speed_mps": float(truth.speed_mps), "quat": truth.quat.tolist(),
            "yaw_rad": truth.yaw_rad + float(rng.normal(0, 0.01)), "pitch_rad": 0.0, "roll_rad": 0.0,
            "att_var_rad2": [1e-4] * 3, "rate_body_radps": [0.0] * 3, "accel_bias_mps2": [0.0] * 3,
            "gyro_bias_radps": [0.0] * 3, "gnss_used": seq // 2, "gnss_rejected": {},
            "input_rejected": {}, "counts": {"imu": seq * 4}, "last_reset": None}


def pilot_state(x_m: float = 0.5, y_m: float = 12.0, yaw_deg: float = 0.0,
                stop_reason: str | None = None) -> dict:
    """A viena.pilot.state/1 sample as the pilot's own model makes it: following a route
    north of the sim's origin (a checkpoint every 10 m) from the car at (x_m, y_m) ENU,
    facing yaw_deg (CCW from north), one setpoint sent; stopped for `stop_reason` if given."""
    from viena.common.geodesy import LocalFrame
    from viena.common.samples.pilot import STATE as PILOT_STATE
    from viena.services.pilot.model.estimate import Estimate
    from viena.services.pilot.model.pilot import Pilot
    from viena.services.pilot.model.route import checked
    from viena.services.sim.model.truth import IST_ORIGIN

    t0 = 1_717_236_000_000_000_000
    frame = LocalFrame(*IST_ORIGIN)
    points = [frame.geodetic_of_enu_exact(0.0, n_m, IST_ORIGIN[2])[:2] for n_m in range(0, 101, 10)]
    lat, lon, _ = frame.geodetic_of_enu_exact(x_m, y_m, IST_ORIGIN[2])
    pilot = Pilot()
    pilot.on_estimate(Estimate(t_ns=t0, mode="navigating", position_valid=True, heading_valid=True,
                               origin=IST_ORIGIN, x_m=x_m, y_m=y_m, yaw_rad=math.radians(yaw_deg),
                               speed_mps=4.0, sigma_h_m=0.05, lat_deg=lat, lon_deg=lon))
    pilot.set_route(checked(points, [None] * len(points), "points"))
    assert pilot.start(t0) is None and pilot.tick(t0 + 10_000_000) is not None
    if stop_reason is not None:
        pilot.stop(stop_reason)
    return PILOT_STATE.decode(PILOT_STATE.encode(pilot.snapshot(t0 + 10_000_000, 7, stop_reason is None)))


def yaw_deg(rad: float) -> float:
    return math.degrees(math.atan2(math.sin(rad), math.cos(rad)))
