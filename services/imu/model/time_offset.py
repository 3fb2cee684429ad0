"""How far the IMU's timestamps are from the GNSS clock, measured from a drive.

A USB-serial adapter's latency timer, a busy Pi or a firmware buffer can stamp IMU samples
tens to hundreds of milliseconds late, and a board with its own clock can be seconds off;
the estimator then fuses an acceleration with the wrong moment of the drive. The
receiver's clock is GPS time, so it is the reference.

The IMU is compared with the GNSS over intervals between fixes (model/motion.py), whatever
the fix rate, on two channels that need no mount:
- turns: the angle the IMU turned about its own up axis (gravity's reaction where it
  stood parked) against the change of the heading the course gives, over 1 to 8 s (a long
  interval holds a whole turn: every fix in it tells the time, not only those where the
  turn starts or ends); a gyro scale and bias are fitted along;
- forces: the specific force it integrated, in its axes at the interval's start, against
  the GNSS velocity change plus gravity in the body axes, turned onto each other by the
  rotation that fits best (Wahba's problem: the mount, fitted anew at every shift).
Every shift of the IMU's stamps gets a misfit per channel; their sum, each channel in
units of its own noise, is least at the offset. A coarse search over +-max_offset_s
(20 ms steps, intervals a span apart) finds where; it refuses a best match at the search's
edge (the clock may be off by more) or a second match nearly as good (turns that repeat).
A fine search (2 ms steps, overlapping intervals, a parabola through the least) gives the
offset, a block bootstrap over 10 s stretches of the drive its uncertainty, widened by
what no drive shows (where in its period a sample belongs: a period over sqrt 12). The
result is the correction to add to the IMU's stamps: t_true = t_stamped + offset_s.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from viena.services.imu.model.fitting import block_weights, bootstrap_sigma
from viena.services.imu.model.motion import SPAN_S, GnssMotion, ImuTrack, at_rest
from viena.services.imu.model.mount import wahba

MAX_OFFSET_S = 5.0                  # the coarse search, either way
COARSE_STEP_S = 0.02
FINE_STEP_S = 0.002
FINE_HALF_WIDTH_S = 0.1
MIN_DRIVING_S = 20.0
#: the share of the GNSS's turns and accelerations the timed IMU must explain
MIN_MATCH = 0.5
#: a second match whose misfit is less than this many times the best's: ambiguous
AMBIGUOUS_RATIO = 2.0
#: the runner-up must be this far from the best to count as another match
RUNNER_UP_APART_S = 0.5
BLOCK_S = 10.0
#: the turns channel's intervals: the gyro's drift over the longest is well below a fix's noise
TURN_SPANS_S = (1.0, 2.0, 4.0, 8.0)


@dataclass(frozen=True)
class TimeOffsetEstimate:
    offset_s: float                 # add to the IMU's stamps
    sigma_s: float                  # block bootstrap over the drive
    correlation: float              # share of the GNSS's turns and accelerations explained (0..1)
    seconds_used: float
    fix_interval_s: float = float("nan")
    runner_up_s: float | None = None    # the next best match of the coarse search ...
    runner_up_ratio: float = float("inf")   # ... and how many times the best's misfit it has
    channels: dict = field(default_factory=dict)    # each channel's match (0..1)

    def __str__(self) -> str:
        return (f"{self.offset_s * 1e3:+.1f} ms +- {self.sigma_s * 1e3:.1f} ms "
                f"(match {self.correlation:.2f}, {self.seconds_used:.0f} s of driving, "
                f"fixes every {self.fix_interval_s:.2f} s)")


class _Turns:
    """The IMU's turn about its up axis against the heading's change, scale and bias fitted."""

    def __init__(self, track: ImuTrack, motion: GnssMotion, i, j):
        self.t, self.turned = track.t_s, track.turned
        self.i = i
        self.a, self.b = motion.t_s[i], motion.t_s[j]
        self.target = motion.yaw_rad[j] - motion.yaw_rad[i]
        self.dt = self.b - self.a

    def misfit(self, shifts: np.ndarray, fit=None) -> tuple[np.ndarray, np.ndarray]:
        """Squared misfits (intervals x shifts) and the fit (scale, bias) per shift."""
        imu = (np.interp(self.b[:, None] - shifts, self.t, self.turned)
               - np.interp(self.a[:, None] - shifts, self.t, self.turned))
        if fit is None:
            dt, y = self.dt[:, None], self.target[:, None]
            sxx, sxd, sdd = (imu * imu).sum(0), (imu * dt).sum(0), (dt * dt).sum()
            sxy, sdy = (imu * y).sum(0), (dt * y).sum()
            det = sxx * sdd - sxd * sxd
            det = np.where(np.abs(det) > 1e-30, det, 1e-30)
            fit = np.column_stack([(sxy * sdd - sxd * sdy) / det, (sxx * sdy - sxd * sxy) / det])
        fit = np.broadcast_to(fit, (len(shifts), 2))
        r = self.target[:, None] - fit[:, 0] * imu - fit[:, 1] * self.dt[:, None]
        return r * r, fit

    def null(self) -> float:
        """The misfit with no IMU at all (a steady turn rate fitted)."""
        c = float(self.dt @ self.target / (self.dt @ self.dt))
        return float(np.sum((self.target - c * self.dt) ** 2))


class _Forces:
    """The IMU's integrated specific force against the GNSS's, the mount fitted per shift."""

    def __init__(self, track: ImuTrack, motion: GnssMotion, i, j):
        self.track, self.i = track, i
        self.a, self.b = motion.t_s[i], motion.t_s[j]
        self.y = motion.body_increments(i, j)

    def misfit(self, shifts: np.ndarray, fit=None) -> tuple[np.ndarray, np.ndarray]:
        u = self.track.increments(self.a[:, None] - shifts, self.b[:, None] - shifts)    # k x s x 3
        if fit is None:
            fit = wahba(np.einsum("ki,ksj->sij", self.y, u))
        fit = np.broadcast_to(fit, (len(shifts), 3, 3))
        r = self.y[:, None, :] - np.einsum("sij,ksj->ksi", fit, u)
        return np.sum(r * r, axis=-1), fit

    def null(self) -> float:
        return float(np.sum((self.y - self.y.mean(axis=0)) ** 2))


def estimate_time_offset(t_s: np.ndarray, accel: np.ndarray, gyro: np.ndarray, motion: GnssMotion,
                         max_offset_s: float = MAX_OFFSET_S, around_s: float | None = None) -> TimeOffsetEstimate:
    """The IMU's time offset from its samples (any axes: board or body, SI) at stamps t_s.
    `around_s`: a known rough offset, searched only +-0.1 s about (no coarse search)."""
    t_s = np.asarray(t_s, float)
    accel, gyro = np.asarray(accel, float), np.asarray(gyro, float)
    rest = at_rest(t_s, accel, gyro, motion, *((0.0, max_offset_s + 1.0) if around_s is None else (around_s, 1.0)))
    track = ImuTrack(t_s, accel, gyro, rest.up, rest.gyro_bias)

    def channels(every_s: float, reach_s: float):
        def inside(span_s: float):
            i, j = motion.intervals(span_s, every_s=min(every_s, span_s))
            keep = (motion.t_s[i] - reach_s >= t_s[0]) & (motion.t_s[j] + reach_s <= t_s[-1])
            return i[keep], j[keep]
        turns = [inside(span) for span in TURN_SPANS_S]
        i, j = inside(SPAN_S)
        return [_Turns(track, motion, np.concatenate([x[0] for x in turns]),
                       np.concatenate([x[1] for x in turns])), _Forces(track, motion, i, j)]

    def enough_driving(reach_s: float) -> float:
        driving_s = motion.moving_seconds(t_s[0] + reach_s, t_s[-1] - reach_s)
        if driving_s < MIN_DRIVING_S:
            raise ValueError(f"{driving_s:.0f} s of driving above walking pace: need at least "
                             f"{MIN_DRIVING_S:.0f} s with turns and speed changes")
        return driving_s

    if around_s is None:
        enough_driving(max_offset_s)
        coarse = channels(SPAN_S, max_offset_s)
        shifts = np.arange(-max_offset_s, max_offset_s + COARSE_STEP_S / 2, COARSE_STEP_S)
        total, matches = _combined(coarse, shifts)
        best = int(np.argmin(total))
        center = float(shifts[best])
        _check_coarse(shifts, total, best, matches, max_offset_s)
        runner = _runner_up(shifts, total, best)
    else:
        center, runner = float(around_s), (None, float("inf"))

    reach = abs(center) + FINE_HALF_WIDTH_S
    driving_s = enough_driving(reach)
    fine = channels(SPAN_S / 4, reach)
    shifts = center + np.arange(-FINE_HALF_WIDTH_S, FINE_HALF_WIDTH_S + FINE_STEP_S / 2, FINE_STEP_S)
    total, matches = _combined(fine, shifts)
    best = int(np.argmin(total))
    offset = _parabola_min(shifts, total, best)
    if max(matches.values()) < MIN_MATCH:
        raise ValueError(_no_match(matches))

    sigma = _uncertainty(fine, shifts, best, motion, float(np.median(np.diff(t_s))))
    return TimeOffsetEstimate(offset, sigma, max(matches.values()), driving_s, motion.fix_interval_s,
                              runner[0], runner[1], {k: round(v, 3) for k, v in matches.items()})


def _uncertainty(fine: list, shifts: np.ndarray, best: int, motion: GnssMotion, period_s: float) -> float:
    """The fine search's offset's sigma: a block bootstrap over the drive, widened by what no
    drive shows (where in its period `period_s` an IMU's sample belongs)."""
    # per-interval misfits with each channel's fit held at the best shift: the bootstrap's
    # rows, each channel in units of its noise, drawn by the same blocks of the drive
    draws, blocks = block_weights([motion.t_s[ch.i] for ch in fine], BLOCK_S)
    replicas = np.zeros((draws[0].shape[0], len(shifts)))
    for ch, draw in zip(fine, draws, strict=True):
        m, fit = ch.misfit(shifts[best:best + 1])
        per, _ = ch.misfit(shifts, fit=fit[0])
        replicas += draw @ (per / (m.sum() / len(m)))
    found = np.array([_parabola_min(shifts, r, int(np.argmin(r))) for r in replicas])
    # plus where in its period an IMU's sample belongs (its mean over the period, or a
    # filtered value at its end), uniform over one period
    return float(np.hypot(bootstrap_sigma(found, blocks), period_s / np.sqrt(12.0)))


def _combined(chans: list, shifts: np.ndarray) -> tuple[np.ndarray, dict]:
    """Sum of each channel's misfit per shift in units of its least mean misfit, and each
    channel's match at the best shift (1 - misfit / misfit without the IMU)."""
    sums = [ch.misfit(shifts)[0].sum(axis=0) for ch in chans]
    total = sum(s / max(s.min() / len(ch.a), 1e-30) for s, ch in zip(sums, chans))
    best = int(np.argmin(total))
    names = ("turns", "forces")
    matches = {n: float(max(0.0, 1.0 - s[best] / max(ch.null(), 1e-30))) for n, s, ch in zip(names, sums, chans)}
    return total, matches


def _check_coarse(shifts, total, best, matches, max_offset_s) -> None:
    if max(matches.values()) < MIN_MATCH:
        raise ValueError(_no_match(matches))
    if abs(shifts[best]) >= max_offset_s - 2 * COARSE_STEP_S:
        raise ValueError(f"the IMU matches the GNSS best at {shifts[best]:+.2f} s, the edge of the "
                         f"+-{max_offset_s:.1f} s search: its clock is further off (search wider, "
                         f"--max-offset-s), or the recording holds another unit's samples")
    shift, ratio = _runner_up(shifts, total, best)
    if shift is not None and ratio < AMBIGUOUS_RATIO:
        raise ValueError(f"the offset is ambiguous: {shifts[best]:+.2f} s and {shift:+.2f} s match "
                         f"almost as well (misfit x{ratio:.1f}): drive turns that do not repeat every "
                         f"{abs(shift - shifts[best]):.1f} s")


def _runner_up(shifts, total, best) -> tuple[float | None, float]:
    """The best local minimum at least RUNNER_UP_APART_S from the best, and its misfit ratio."""
    inner = np.flatnonzero((total[1:-1] < total[:-2]) & (total[1:-1] <= total[2:])) + 1
    far = inner[np.abs(shifts[inner] - shifts[best]) >= RUNNER_UP_APART_S]
    if not len(far):
        return None, float("inf")
    k = int(far[np.argmin(total[far])])
    return float(shifts[k]), float(total[k] / total[best])


def _no_match(matches: dict) -> str:
    shown = ", ".join(f"{k} {v:.2f}" for k, v in matches.items())
    return (f"the IMU does not match the GNSS at any offset (share explained: {shown}; need "
            f"{MIN_MATCH}): a drive without turns or speed changes, or another unit's samples")


def _parabola_min(shifts: np.ndarray, cost: np.ndarray, i: int) -> float:
    s = float(shifts[i])
    if 0 < i < len(shifts) - 1:
        a, b, c = cost[i - 1], cost[i], cost[i + 1]
        denom = a - 2 * b + c
        if denom > 0:
            s += float(0.5 * (a - c) / denom * (shifts[1] - shifts[0]))
    return s
