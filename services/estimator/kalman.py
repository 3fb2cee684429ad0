"""Loosely coupled Kalman filter in ENU: position, velocity, accelerometer bias, tilt
error and each GNSS receiver's slowly wandering error.

State x = [p_E p_N p_U, v_E v_N v_U, b_x b_y b_z | t_E t_N | g_E g_N g_U per receiver]:
- p, v: the body origin's position and velocity in the local ENU frame;
- b: the accelerometer bias in body axes;
- t (with `tilt=True`): the attitude's tilt error, a small rotation about the East and
  North axes, R_true = (I + [t x]) R. It is an error state: the estimator turns the
  attitude by it after each update and sets it back to zero (`take_tilt`). GNSS velocity
  sees it through the specific force, dv/dt = t x f (Groves 2013, eq. 14.? of the
  loosely coupled INS/GNSS filter), which is how the tilt is told apart from the bias:
  the bias turns with the car, a tilt error does not;
- g (one block per receiver, `receiver(unit)`): what makes a receiver's fixes wrong
  together for minutes (satellite orbits and clocks, the atmosphere: docs/sensors.md#gnss-error-budget), a
  first-order Gauss-Markov process of correlation time `gnss_bias_tau_s` (Brown & Hwang
  2012, ch. 2; Groves 2013, ch. 9 on GNSS error correlation). A fix measures p + R l + g
  plus white noise. Receivers on one car share one sky: their blocks are correlated
  (coefficient `gnss_common_fraction`) while their solutions are of one kind (`group`:
  a single-point error and an RTK one share nothing); a receiver whose solution changes
  kind gets a new error (`reset_receiver`).

The IMU drives the prediction (`a_enu = R (f - b) - g`); GNSS position and velocity,
non-holonomic and zero-velocity pseudo-measurements correct it. The yaw is not a state
(the heading filter owns it).

The mean is kept in plain floats and moved every IMU sample; the covariance is moved in
one step over the time gathered since its last move, at a slower rate and always before
a measurement -- the usual split of strapdown mean and filter covariance, and what lets an
offline run go through tens of thousands of IMU samples per second.
Equations: docs/estimator.md#position-and-velocity-the-kalman-filter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from viena.services.estimator.kalman_update import _I3, B_, P_, T_, V_, Diverged, KalmanUpdates

#: the core states (position, velocity, accelerometer bias: P_, V_, B_ in kalman_update.py)
N = 9
#: what drove the mean since the covariance last moved: nothing known, the IMU's vertical
#: acceleration only (the yaw unknown), the IMU's whole
FREE, VERTICAL, FULL = 0, 1, 2


@dataclass
class KalmanNoise:
    accel_psd: float = 0.05          # (m/s^2)^2/Hz: accelerometer noise plus tilt error
    bias_walk_psd: float = 1e-6      # (m/s^2)^2/s: accelerometer bias random walk
    free_accel_psd: float = 4.0      # (m/s^2)^2/Hz: unknown acceleration when not IMU-driven
    #: initial accelerometer bias uncertainty, body x, y, z (m/s^2): levelling takes the
    #: horizontal bias into the tilt, so only what the tilt states do not carry is left
    bias_sigma0: tuple = (0.05, 0.05, 0.2)
    tilt_psd: float = 1e-7           # rad^2/s: the attitude's tilt random walk
    tilt_sigma0: float = math.radians(0.5)
    gnss_tau_s: float = 600.0        # correlation time of a receiver's error
    gnss_rho: float = 0.8            # correlation of two receivers' errors (one sky)
    #: the receivers' errors as consider states (Schmidt): their uncertainty is in every
    #: gain and covariance, their estimate is never moved (docs/estimator.md#receiver-errors)
    gnss_consider: bool = True
    gravity: float = 9.80665


class NavKalman(KalmanUpdates):
    """The filter. `x` is a list of `n` floats, `P` an n x n array."""

    #: covariance beyond these is not an estimate any more (variances, m^2 and (m/s)^2)
    MAX_POS_VAR = 1e8
    MAX_VEL_VAR = 1e4

    def __init__(self, noise: KalmanNoise | None = None, tilt: bool = False):
        self.noise = noise or KalmanNoise()
        self.tilt = tilt
        self.core = N + (2 if tilt else 0)
        self.receivers: dict[str, int] = {}    # unit -> first index of its error block
        #: the IMU-driven process noise times this (consistency.py: an adaptive Q)
        self.q_scale = 1.0
        self._sigma: dict[str, tuple] = {}     # unit -> its error's stationary sigmas (E, N, U)
        self._group: dict[str, str] = {}       # unit -> its solution's kind: who shares its sky
        self._h_cache: dict[tuple, np.ndarray] = {}     # (kind, n, k) -> H rows (`_rows`)
        self.initialized = False
        self._size(self.core)

    def _size(self, n: int) -> None:
        self.n = n
        self.x = [0.0] * n
        self.P = np.eye(n)
        self._pending_dt = 0.0          # time the mean moved since the covariance last did
        self._pending_mode = FREE       # ... driven by the IMU (FULL, VERTICAL) or not (FREE)
        self._pending_rot = None        # body->ENU rotation to couple the bias with
        self._f_dt = [0.0, 0.0, 0.0]    # ... and the specific force (ENU) times time
        self._flushes = 0

    def initialize(self, pos, pos_cov, vel, vel_cov, unit: str | None = None) -> None:
        """Position and velocity from a fix of `unit` (white covariance `pos_cov`): the
        fix measured p + g_unit, so p's error is minus that receiver's error (and noise)."""
        nz = self.noise
        self.x = [float(v) for v in (*pos, *vel)] + [0.0] * (self.n - 6)
        P = np.zeros((self.n, self.n))
        P[P_, P_] = pos_cov
        P[V_, V_] = vel_cov
        P[B_, B_] = np.diag(np.square(nz.bias_sigma0))
        if self.tilt:
            P[T_, T_] = np.eye(2) * nz.tilt_sigma0 ** 2
        units = list(self.receivers)
        for i, a in enumerate(units):
            for b in units[i:]:
                block = self._prior(a, b)
                ia, ib = self.receivers[a], self.receivers[b]
                P[ia:ia + 3, ib:ib + 3] = block
                P[ib:ib + 3, ia:ia + 3] = block.T
        if unit in self.receivers:
            k = self.receivers[unit]
            gk = P[k:k + 3, :].copy()           # cov(g_unit, .), zero for p so far
            P[P_, :] = -gk                      # p's error is -g_unit - noise
            P[:, P_] = -gk.T
            P[P_, P_] = np.asarray(pos_cov) + gk[:, k:k + 3]
        self.P = P
        self._pending_dt = 0.0
        self.initialized = True

    def reset(self) -> None:
        self.initialized = False
        self.receivers.clear()
        self._sigma.clear()
        self._group.clear()
        self._size(self.core)

    # -- the receivers' errors ---------------------------------------------------------------
    def receiver(self, unit: str, sigma_enu, group: str = "") -> int:
        """The first state of `unit`'s error block, made on first use with stationary
        sigmas `sigma_enu` (m, E N U) and the prior correlation to the receivers before
        of the same `group` (their solutions' kind)."""
        k = self.receivers.get(unit)
        if k is not None:
            return k
        n = self.n
        k = n
        x, P = self.x + [0.0, 0.0, 0.0], np.zeros((n + 3, n + 3))
        P[:n, :n] = self.P
        pending = (self._pending_dt, self._pending_mode, self._pending_rot, self._f_dt)
        self.n, self.x, self.P = n + 3, x, P
        self._pending_dt, self._pending_mode, self._pending_rot, self._f_dt = pending
        self.receivers[unit] = k
        self._fill(unit, sigma_enu, group)
        return k

    def reset_receiver(self, unit: str, sigma_enu, group: str) -> None:
        """`unit`'s solution changed kind (single to RTK fixed, fixed back to single): its
        error now is another one, unrelated to the old one nor to the estimate's error so
        far, of sigmas `sigma_enu`. So the step its fixes make goes into this new error's
        uncertainty, not into the position; the position's own uncertainty (what it owes
        to the old error) stays, for the new fixes to correct."""
        self.flush()
        k = self.receivers[unit]
        self.x[k:k + 3] = [0.0, 0.0, 0.0]
        self.P[k:k + 3, :] = 0.0
        self.P[:, k:k + 3] = 0.0
        self._fill(unit, sigma_enu, group)

    def _fill(self, unit: str, sigma_enu, group: str) -> None:
        """A fresh error block for `unit` (its rows zero): alone in its group, its
        stationary covariance; else g = c g_first + e, what the shared sky makes of it
        through the group's first receiver, and its own part."""
        k = self.receivers[unit]
        sigma = tuple(float(v) for v in sigma_enu)
        first = next((u for u, g in self._group.items() if g == group and u != unit), None)
        P = self.P
        if first is not None:
            f = self.receivers[first]
            c = np.diag([self.noise.gnss_rho * a / b for a, b in zip(sigma, self._sigma[first])])
            row = c @ P[f:f + 3, :]
            P[k:k + 3, :] = row
            P[:, k:k + 3] = row.T
            P[k:k + 3, k:k + 3] = (c @ P[f:f + 3, f:f + 3] @ c
                                   + np.diag(np.square(sigma)) * (1.0 - self.noise.gnss_rho ** 2))
            self.x[k:k + 3] = list(c @ np.array(self.x[f:f + 3]))
        else:
            P[k:k + 3, k:k + 3] = np.diag(np.square(sigma))
        self._sigma[unit] = sigma
        self._group[unit] = group

    def receiver_group(self, unit: str) -> str | None:
        """The kind of solution `unit`'s error block was made for (None: it has none)."""
        return self._group.get(unit)

    def rescale_receiver(self, unit: str, sigma_enu) -> None:
        """The receiver's error has another size now (its sigmas changed): the error is
        sigma z with z the same unit-variance process, so its state and covariance scale."""
        k = self.receivers[unit]
        old = self._sigma[unit]
        sigma = tuple(float(v) for v in sigma_enu)
        if sigma == old:
            return
        ratios = [a / b for a, b in zip(sigma, old)]
        P = self.P
        for i, r in enumerate(ratios):
            self.x[k + i] *= r
            P[k + i, :] *= r
            P[:, k + i] *= r
        self._sigma[unit] = sigma

    def receiver_error(self, unit: str) -> list[float]:
        k = self.receivers.get(unit)
        return [0.0, 0.0, 0.0] if k is None else self.x[k:k + 3]

    def _prior(self, a: str, b: str) -> np.ndarray:
        """The stationary covariance of two receivers' errors."""
        sa, sb = self._sigma[a], self._sigma[b]
        c = 1.0 if a == b else self.noise.gnss_rho if self._group[a] == self._group[b] else 0.0
        return np.diag([c * u * v for u, v in zip(sa, sb)])

    # -- prediction -----------------------------------------------------------------------
    def move(self, ae: float, an: float, au: float, dt: float, rot=None, vertical: bool = False) -> None:
        """Move the mean by dt under ENU acceleration (ae, an, au); the covariance later.

        `rot` is the body->ENU rotation (9 floats, row-major) when the acceleration came from
        the IMU, so the bias and tilt are coupled in; None means the acceleration is unknown
        and the covariance grows as for a constant-velocity model. `vertical`: only the
        vertical acceleration came from the IMU (the yaw is unknown), the horizontal is free.
        """
        x = self.x
        h = 0.5 * dt * dt
        x[0] += x[3] * dt + ae * h
        x[1] += x[4] * dt + an * h
        x[2] += x[5] * dt + au * h
        x[3] += ae * dt
        x[4] += an * dt
        x[5] += au * dt
        self._pending_dt += dt
        if rot is not None:
            self._pending_mode = VERTICAL if vertical else FULL
            self._pending_rot = rot
            f = self._f_dt
            f[0] += ae * dt
            f[1] += an * dt
            f[2] += au * dt

    def flush(self) -> None:
        """Move the covariance over the gathered time: P <- F P F^T + Q."""
        T = self._pending_dt
        if T <= 0.0:
            return
        n, nz = self.n, self.noise
        F = np.eye(n)
        F[P_, V_] = _I3 * T
        mode = self._pending_mode
        if mode != FREE:
            rows = slice(0, 3) if mode == FULL else slice(2, 3)
            R = np.array(self._pending_rot).reshape(3, 3)[rows]
            F[3:6][rows, B_] = -T * R
            F[0:3][rows, B_] = -0.5 * T * T * R
            if self.tilt:
                # dv/dt = t x f, f the mean specific force in ENU over the interval
                fe, fn, fu = (v / T for v in self._f_dt)
                fu += nz.gravity
                Ft = np.array(((0.0, fu), (-fu, 0.0), (fn, -fe)))[rows]
                F[3:6][rows, T_] = T * Ft
                F[0:3][rows, T_] = 0.5 * T * T * Ft
        qs = self.q_scale
        q_h = nz.accel_psd * qs if mode == FULL else nz.free_accel_psd
        q_v = nz.accel_psd * qs if mode != FREE else nz.free_accel_psd
        a = math.exp(-T / nz.gnss_tau_s) if nz.gnss_tau_s > 0 else 0.0
        for k in self.receivers.values():
            F[k, k] = F[k + 1, k + 1] = F[k + 2, k + 2] = a
        P = F @ self.P @ F.T
        # white acceleration noise integrated into velocity and position, bias random walk
        for i in range(3):
            q = q_h if i < 2 else q_v
            q3, q2 = q * T ** 3 / 3.0, q * T * T / 2.0
            P[i, i] += q3
            P[i, i + 3] += q2
            P[i + 3, i] += q2
            P[i + 3, i + 3] += q * T
            P[i + 6, i + 6] += nz.bias_walk_psd * qs * T
        if self.tilt:
            P[9, 9] += nz.tilt_psd * qs * T
            P[10, 10] += nz.tilt_psd * qs * T
        if self.receivers:
            # the receivers' errors: Q = prior (1 - a^2), so they stay at their size
            units = list(self.receivers)
            for i, u in enumerate(units):
                for v in units[i:]:
                    block = self._prior(u, v) * (1.0 - a * a)
                    ku, kv = self.receivers[u], self.receivers[v]
                    P[ku:ku + 3, kv:kv + 3] += block
                    if u != v:
                        P[kv:kv + 3, ku:ku + 3] += block.T
        self._flushes += 1
        if not self._flushes & 15:
            P = 0.5 * (P + P.T)         # what the updates' rounding made asymmetric
        self.P = P
        self._pending_dt = 0.0
        self._pending_mode = FREE
        self._f_dt = [0.0, 0.0, 0.0]
        self.check()

    def retilt(self, sigma_rad: float) -> None:
        """The attitude was aligned afresh: its tilt error is new, uncorrelated with the
        rest, of this sigma."""
        if not self.tilt:
            return
        x, P = self.x, self.P
        x[9] = x[10] = 0.0
        P[T_, :] = 0.0
        P[:, T_] = 0.0
        P[T_, T_] = np.eye(2) * sigma_rad ** 2

    def take_tilt(self) -> tuple[float, float]:
        """The tilt error estimated so far (rad, about East and North), handed over to be
        taken off the attitude: the state goes back to zero."""
        if not self.tilt:
            return 0.0, 0.0
        x = self.x
        te, tn = x[9], x[10]
        x[9] = x[10] = 0.0
        return te, tn

    def check(self) -> None:
        d = self.P.diagonal().tolist()
        total = sum(d) + sum(self.x)            # finite if and only if every term is
        if total - total != 0.0:
            raise Diverged("state or covariance not finite")
        if min(d) < -1e-9:
            raise Diverged("negative variance")
        if max(d[0], d[1], d[2]) > self.MAX_POS_VAR or max(d[3], d[4], d[5]) > self.MAX_VEL_VAR:
            raise Diverged("covariance blew up")
