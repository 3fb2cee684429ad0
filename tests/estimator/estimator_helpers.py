"""Running the estimator over a simulated drive and scoring it against the truth."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmarks.simdrive import Drive, DriveSamples
from viena.common.rotation import wrap_angle
from viena.common.samples.estimator import STATE
from viena.services.estimator.angles import yaw_pitch_roll
from viena.services.estimator.estimator import Estimator


@dataclass
class Scored:
    t_s: np.ndarray            # truth time of each scored state
    pos_err: np.ndarray        # ENU, m
    vel_err: np.ndarray
    yaw_err: np.ndarray        # rad
    pitch_err: np.ndarray
    roll_err: np.ndarray
    speed: np.ndarray          # true speed
    heading_valid: np.ndarray
    gnss_err: np.ndarray       # raw GNSS position error (antenna, ENU) of every usable fix
    final: dict                # the last state
    estimator: Estimator

    @staticmethod
    def rms(values, mask=None) -> float:
        """Root mean square of scalars, or of the lengths of vectors (rows)."""
        v = np.asarray(values if mask is None else values[mask], float)
        sq = np.sum(v * v, axis=1) if v.ndim > 1 else v * v
        return float(np.sqrt(np.mean(sq)))

    @property
    def horizontal_rmse(self) -> float:
        return self.rms(self.pos_err[:, :2])

    @property
    def gnss_horizontal_rmse(self) -> float:
        return self.rms(self.gnss_err[:, :2])


def generate(drive: Drive) -> tuple[list, tuple]:
    samples = DriveSamples(drive)
    return list(samples), samples.origin


def without_mag(samples: list) -> list:
    out = []
    for kind, s, truth in samples:
        if kind == "imu":
            s = dict(s, mag_T=None)
        out.append((kind, s, truth))
    return out


def run(samples: list, settings: dict, every: int = 4, check_schema: bool = False) -> Scored:
    """Feed the drive in time order; score the state after every `every`-th IMU sample."""
    est = Estimator(settings)
    rows, gnss = [], []
    n = 0
    state = None
    for kind, sample, truth in samples:
        if kind == "gnss":
            est.add_gnss(sample)
            if sample["valid"]:
                gnss.append(est.frame.enu_of_ecef(sample["ecef_m"]) - truth)
            continue
        est.add_imu(sample)
        n += 1
        if n % every:
            continue
        state = est.state()
        if check_schema:
            STATE.encode(dict(state))
        if not state["position_valid"]:
            continue
        yaw, pitch, roll = yaw_pitch_roll(truth.quat)
        rows.append((truth.t_s, *(np.array(state["enu_m"]) - truth.enu_m),
                     *(np.array(state["vel_enu_mps"]) - truth.vel_enu_mps),
                     wrap_angle(state["yaw_rad"] - yaw), state["pitch_rad"] - pitch,
                     state["roll_rad"] - roll, truth.speed_mps, state["heading_valid"]))
    a = np.array(rows, float)
    return Scored(a[:, 0], a[:, 1:4], a[:, 4:7], a[:, 7], a[:, 8], a[:, 9], a[:, 10],
                  a[:, 11] > 0, np.array(gnss), est.state(), est)


def settings_for(drive: Drive, origin, **extra) -> dict:
    """The drive's origin and lever arm. Receivers are used from their first fix
    (`admit_hold_s` 0): these tests are about what the filter does with fixes from the
    start; the admission's 10 s hold has its own (test_estimator_admission.py)."""
    s = {"origin": list(origin), "gnss_lever_arm_m": {"gnss0": list(drive.lever_arm_m)}, "admit_hold_s": 0.0}
    s.update(extra)
    return s


def deg(x: float) -> float:
    return math.degrees(x)
