"""How far the IMU's timestamps are from the GNSS clock, measured from a drive.

A USB-serial adapter's latency timer, a busy Pi or a firmware buffer can stamp IMU samples
tens to hundreds of milliseconds late; the estimator then fuses an acceleration with the
wrong moment of the drive. The receiver's clock is GPS time, so it is the reference.

`estimate_time_offset` slides the IMU's body-frame yaw rate against the yaw rate of the GNSS
course, and its forward acceleration against the GNSS speed change, and finds the shift
where they agree best (cross-correlation, both signals smoothed alike so smoothing adds
no delay of its own). The result is the correction to add to the IMU's stamps:
t_true = t_stamped + offset_s. Its uncertainty comes from splitting the drive into parts
and seeing how much the parts disagree.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.services.imu.model.motion import GnssMotion, moving_average

STEP_S = 0.02                       # the common time grid (50 Hz)


@dataclass(frozen=True)
class TimeOffsetEstimate:
    offset_s: float                 # add to the IMU's stamps
    sigma_s: float                  # from how much the drive's parts disagree
    correlation: float              # how alike the signals are at the best shift (0..1)
    parts: tuple[float, ...]        # each part's own estimate (of the surest signal)
    seconds_used: float

    def __str__(self) -> str:
        return (f"{self.offset_s * 1e3:+.1f} ms +- {self.sigma_s * 1e3:.1f} ms "
                f"(correlation {self.correlation:.2f}, {self.seconds_used:.0f} s of driving)")


def body_signals(t_s: np.ndarray, accel_body: np.ndarray, gyro_body: np.ndarray,
                 smooth_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(yaw rate, forward specific force), smoothed as the GNSS derivatives are."""
    rate = moving_average(t_s, np.asarray(gyro_body, float)[:, 2], smooth_s)
    forward = moving_average(t_s, np.asarray(accel_body, float)[:, 1], smooth_s)
    return rate, forward


def estimate_time_offset(t_s: np.ndarray, accel_body: np.ndarray, gyro_body: np.ndarray,
                         motion: GnssMotion, max_offset_s: float = 1.0, smooth_s: float = 0.3,
                         parts: int = 4) -> TimeOffsetEstimate:
    """The IMU's time offset from body-frame samples (mount applied) at stamps t_s."""
    t_s = np.asarray(t_s, float)
    rate, forward = body_signals(t_s, accel_body, gyro_body, smooth_s)
    lo = max(t_s[0], motion.t_s[0]) + max_offset_s
    hi = min(t_s[-1], motion.t_s[-1]) - max_offset_s
    grid = np.arange(lo, hi, STEP_S)
    moving = np.interp(grid, motion.t_s, motion.moving.astype(float)) > 0.99
    if moving.sum() * STEP_S < 20.0:
        raise ValueError(f"{moving.sum() * STEP_S:.0f} s of driving above walking pace: need at least "
                         f"20 s with turns and speed changes")
    reference = [np.interp(grid, motion.t_s, motion.yaw_rate_radps),
                 np.interp(grid, motion.t_s, motion.forward_accel_mps2)]
    shifts = np.arange(-max_offset_s, max_offset_s + STEP_S / 2, STEP_S / 2)
    # the IMU stamped t - offset saw what happened at t: compare imu(t - s) with gnss(t)
    shifted = [[np.interp(grid - s, t_s, x) for s in shifts] for x in (rate, forward)]

    channels = []
    for ref, candidates in zip(reference, shifted, strict=True):
        whole = _best_shift(shifts, ref, candidates, moving)
        if whole is None:
            continue
        pieces = []
        for piece in np.array_split(np.flatnonzero(moving), parts):
            mask = np.zeros_like(moving)
            mask[piece] = True
            found = _best_shift(shifts, ref, candidates, mask)
            if found is not None:
                pieces.append(found[0])
        if len(pieces) > 1:
            sigma = max(float(np.std(pieces, ddof=1) / math.sqrt(len(pieces))), STEP_S / 10)
            channels.append((whole[0], sigma, whole[1], pieces))
    if not channels:
        raise ValueError("the drive has neither turns nor speed changes to time the IMU by")
    # each channel counts as much as it is sure: a drive at steady speed says little by its
    # forward acceleration, a straight road little by its yaw rate
    weights = np.array([1.0 / c[1] ** 2 for c in channels])
    offset = float(np.sum(weights * [c[0] for c in channels]) / weights.sum())
    sigma = float(1.0 / math.sqrt(weights.sum()))
    correlation = float(np.sum(weights * [c[2] for c in channels]) / weights.sum())
    best_channel = channels[int(np.argmax(weights))]
    return TimeOffsetEstimate(offset, sigma, correlation, tuple(best_channel[3]),
                              float(moving.sum() * STEP_S))


def _best_shift(shifts: np.ndarray, ref: np.ndarray, candidates: list, mask: np.ndarray):
    """(shift, correlation) where one IMU signal best matches the GNSS one, or None when
    the GNSS signal does not vary (nothing to match)."""
    r = ref[mask] - ref[mask].mean()
    spread = [c[mask] - c[mask].mean() for c in candidates]
    if np.dot(r, r) <= 1e-12 or min(np.dot(x, x) for x in spread) <= 1e-12:
        return None
    score = np.array([np.dot(r, x) / math.sqrt(np.dot(r, r) * np.dot(x, x)) for x in spread])
    i = int(np.argmax(score))
    s = float(shifts[i])
    if 0 < i < len(shifts) - 1:                              # a parabola through the peak
        a, b, c = score[i - 1], score[i], score[i + 1]
        denom = a - 2 * b + c
        if denom < 0:
            s += 0.5 * (a - c) / denom * float(shifts[1] - shifts[0])
    return s, float(score[i])
