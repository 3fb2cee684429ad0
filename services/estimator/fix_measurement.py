"""A GNSS fix as a measurement: values in, values out, nothing of the filters changed.

`position` is the fix's ENU position and covariance (no surer than its kind's floor),
`antenna` the lever arm and the body origin's velocity, `noise` the split of its variance
into a white part and the receiver's wandering error (gnss_update.py applies them;
docs/estimator.md#gnss-update-and-lever-arm).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.common.geodesy import LocalFrame
from viena.common.samples.fix import Fix
from viena.services.estimator.attitude import cross, rotate
from viena.services.estimator.gnss_noise import WhiteShare, carrier_share

#: the largest white share: a receiver is never taken as having no wandering error at all
MAX_WHITE_SHARE = 0.98
#: the size of a receiver's wandering error follows its sigmas over this long (s)
LEVEL_TAU_S = 30.0
#: the least wandering error's sigma (m): a fixed RTK solution has none, but the Kalman
#: filter's receiver block must keep a size (it is rescaled by ratios)
MIN_WANDER_M = 0.001


@dataclass(frozen=True)
class Pose:
    """What a fix's measurement needs of the attitude."""
    rot: tuple                  # body -> ENU, row-major
    rate: tuple                 # the bias-corrected gyro (rad/s)
    known: bool                 # aligned and the yaw known: the arm's direction is


@dataclass(frozen=True)
class FixNoise:
    """A fix's variance split: `white_cov` its white part, `wander` the sigmas of the
    receiver's wandering error, `level` the receiver's smoothed variance (E, N, U, t)."""
    white_cov: np.ndarray
    wander: tuple[float, float, float]
    level: tuple


def position(fix: Fix, frame: LocalFrame, floor) -> tuple[tuple, np.ndarray]:
    """The antenna's ENU position and covariance, no surer than the kind's `floor`."""
    z = frame.enu_of_ecef(fix.ecef_m)
    if fix.enu_sigma_m is not None:
        cov = np.diag(np.square(fix.enu_sigma_m))
    else:
        cov = frame.cov_to_enu(fix.ecef_sigma_m)
    if floor is not None:               # no receiver is surer than its kind allows
        cov = cov + np.diag(np.maximum(0.0, np.square(floor) - cov.diagonal()))
    return z, cov


def antenna(fix: Fix, frame: LocalFrame, pose: Pose, lever, imu_mode: bool, vel_sigma_default: float):
    """(arm, vel, velR): the lever arm in ENU (zero while its direction is unknown) and the
    body origin's velocity with its covariance (None without one)."""
    r, known = pose.rot, pose.known
    arm = rotate(r, lever) if known else (0.0, 0.0, 0.0)
    if fix.vel_ecef_mps is None:
        return arm, None, None
    vel = frame.vector_to_enu(fix.vel_ecef_mps)
    velR = frame.cov_to_enu(fix.vel_sigma_mps or (vel_sigma_default,) * 3)
    # the antenna moves with the car's turning: v_ant = v + R (w x r)
    w = pose.rate if imu_mode else (0.0, 0.0, 0.0)
    arm_v = rotate(r, cross(w, lever)) if known else (0.0, 0.0, 0.0)
    return arm, (vel[0] - arm_v[0], vel[1] - arm_v[1], vel[2] - arm_v[2]), velR


def noise(cov: np.ndarray, floor, share: WhiteShare, smoothed: tuple | None, t: int) -> FixNoise:
    """The fix's variance: a white part, and the receiver's wandering error, whose size
    follows the receiver's sigmas over LEVEL_TAU_S, not each fix's: one fix with a wild
    sigma says little about the sky's error. A carrier-phase receiver's growing sigma is
    its corrections ageing (an RTK solution extrapolates them: centimetres a second): that
    size counts at once; its white part is up to its kind's floor."""
    if share.learns:
        sh, sv = min(MAX_WHITE_SHARE, share.horizontal), min(MAX_WHITE_SHARE, share.vertical)
    else:
        sh = carrier_share(0.5 * float(cov[0, 0] + cov[1, 1]), None if floor is None else floor[0])
        sv = carrier_share(float(cov[2, 2]), None if floor is None else floor[2])
    d = np.array([math.sqrt(sh), math.sqrt(sh), math.sqrt(sv)])
    var = cov.diagonal()
    level: list[float]
    if smoothed is None:
        level = var.tolist()
    else:
        k = min(1.0, max(0.0, (t - smoothed[3]) * 1e-9) / LEVEL_TAU_S)
        level = [smoothed[i] + k * (var[i] - smoothed[i]) for i in range(3)]
        if not share.learns:
            level = [max(level[i], var[i]) for i in range(3)]
    if share.learns:
        wander_var = ((1.0 - sh) * level[0], (1.0 - sh) * level[1], (1.0 - sv) * level[2])
    elif floor is not None:             # what a carrier-phase receiver says beyond its noise
        wander_var = (level[0] - floor[0] * floor[0], level[1] - floor[1] * floor[1],
                      level[2] - floor[2] * floor[2])
    else:
        wander_var = (0.0, 0.0, 0.0)
    w = tuple(max(MIN_WANDER_M, math.sqrt(max(0.0, v))) for v in wander_var)
    return FixNoise(cov * np.outer(d, d), (w[0], w[1], w[2]), (*level[:3], t))
