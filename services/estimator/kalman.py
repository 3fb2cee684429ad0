"""Loosely coupled Kalman filter in ENU: position, velocity and accelerometer bias.

State x = [p_E p_N p_U, v_E v_N v_U, b_x b_y b_z]: the body origin's position and
velocity in the local ENU frame, and the accelerometer bias in body axes. The IMU drives
the prediction (`a_enu = R (f - b) - g`); GNSS position and velocity, non-holonomic and
zero-velocity pseudo-measurements correct it. Attitude is not a state here (Madgwick owns
it), so the filter is small: 9 states.

The mean is kept in plain floats and moved every IMU sample; the covariance is moved in
one step over the time gathered since its last move, at a slower rate and always before
a measurement -- the usual split of strapdown mean and filter covariance, and what lets an
offline run go through tens of thousands of IMU samples per second.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N = 9
P_, V_, B_ = slice(0, 3), slice(3, 6), slice(6, 9)
_I3 = np.eye(3)
# flat indices of the transition's time-dependent entries: p <- v, v <- b, p <- b
_F_INDEX = np.array([i * N + i + 3 for i in range(3)]
                    + [(3 + i) * N + 6 + j for i in range(3) for j in range(3)]
                    + [i * N + 6 + j for i in range(3) for j in range(3)])
# flat indices of the process noise entries: pp diagonal, pv and vp, vv, bb
_Q_INDEX = np.array([i * N + i for i in range(3)] + [i * N + i + 3 for i in range(3)]
                    + [(i + 3) * N + i for i in range(3)] + [(i + 3) * N + i + 3 for i in range(3)]
                    + [(i + 6) * N + i + 6 for i in range(3)])


@dataclass
class KalmanNoise:
    accel_psd: float = 0.05          # (m/s^2)^2/Hz: accelerometer noise plus tilt error
    bias_walk_psd: float = 1e-6      # (m/s^2)^2/s: accelerometer bias random walk
    free_accel_psd: float = 4.0      # (m/s^2)^2/Hz: unknown acceleration when not IMU-driven
    bias_sigma0: float = 0.2         # m/s^2: initial accelerometer bias uncertainty


class Diverged(Exception):
    """The covariance blew up or a number stopped being finite."""


class NavKalman:
    """The filter. `x` is a list of 9 floats, `P` a 9x9 array."""

    #: covariance beyond these is not an estimate any more (variances, m^2 and (m/s)^2)
    MAX_POS_VAR = 1e8
    MAX_VEL_VAR = 1e4

    def __init__(self, noise: KalmanNoise | None = None):
        self.noise = noise or KalmanNoise()
        self.x = [0.0] * N
        self.P = np.eye(N)
        self.initialized = False
        self._pending_dt = 0.0          # time the mean moved since the covariance last did
        self._pending_imu = False       # ... driven by the IMU (else free acceleration)
        self._pending_rot = None        # body->ENU rotation to couple the bias with
        self._F = np.eye(N)             # transition matrix, blocks rewritten per step
        self._flushes = 0

    def initialize(self, pos, pos_cov, vel, vel_cov, bias=(0.0, 0.0, 0.0)) -> None:
        self.x = [float(v) for v in (*pos, *vel, *bias)]
        self.P = np.zeros((N, N))
        self.P[P_, P_] = pos_cov
        self.P[V_, V_] = vel_cov
        self.P[B_, B_] = _I3 * self.noise.bias_sigma0 ** 2
        self._pending_dt = 0.0
        self.initialized = True

    def reset(self) -> None:
        self.initialized = False
        self._pending_dt = 0.0

    # -- prediction -----------------------------------------------------------------------
    def move(self, ae: float, an: float, au: float, dt: float, rot=None) -> None:
        """Move the mean by dt under ENU acceleration (ae, an, au); the covariance later.

        `rot` is the body->ENU rotation (9 floats, row-major) when the acceleration came from
        the IMU, so the bias is coupled in; None means the acceleration is unknown and the
        covariance grows as for a constant-velocity model.
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
            self._pending_imu = True
            self._pending_rot = rot

    def flush(self) -> None:
        """Move the covariance over the gathered time: P <- F P F^T + Q."""
        T = self._pending_dt
        if T <= 0.0:
            return
        F = self._F
        if self._pending_imu:
            r0, r1, r2, r3, r4, r5, r6, r7, r8 = self._pending_rot
            h = -0.5 * T * T
            F.flat[_F_INDEX] = (T, T, T, -T * r0, -T * r1, -T * r2, -T * r3, -T * r4, -T * r5,
                                -T * r6, -T * r7, -T * r8, h * r0, h * r1, h * r2, h * r3, h * r4,
                                h * r5, h * r6, h * r7, h * r8)
            q_acc = self.noise.accel_psd
        else:
            F.flat[_F_INDEX] = (T, T, T) + (0.0,) * 18
            q_acc = self.noise.free_accel_psd
        P = F @ self.P @ F.T
        # white acceleration noise integrated into velocity and position, bias random walk
        q3, q2, q1 = q_acc * T ** 3 / 3.0, q_acc * T * T / 2.0, q_acc * T
        qb = self.noise.bias_walk_psd * T
        P.flat[_Q_INDEX] += (q3, q3, q3, q2, q2, q2, q2, q2, q2, q1, q1, q1, qb, qb, qb)
        self._flushes += 1
        if not self._flushes & 15:
            P = 0.5 * (P + P.T)         # what the updates' rounding made asymmetric
        self.P = P
        self._pending_dt = 0.0
        self._pending_imu = False
        self.check()

    # -- measurement ------------------------------------------------------------------------
    def update(self, H: np.ndarray, innovation, R: np.ndarray, gate_chi2: float | None = None):
        """Correct with z - H x = `innovation`, z ~ N(H x, R).

        Returns (accepted, d2, dx): d2 is the squared Mahalanobis distance of the innovation,
        dx the correction applied (None if the gate refused it).
        """
        self.flush()
        PHt = self.P @ H.T
        return self._gated(PHt, H @ PHt + R, innovation, gate_chi2)

    def update_states(self, first: int, innovation, R: np.ndarray, gate_chi2: float | None = None):
        """`update` for a direct measurement of states first.. first+len(innovation)-1
        (GNSS position is states 0-2, velocity 3-5): no H products."""
        self.flush()
        sl = slice(first, first + len(innovation))
        PHt = self.P[:, sl]
        return self._gated(PHt, PHt[sl] + R, innovation, gate_chi2)

    def update_fix(self, nu_p, R_p, nu_v=None, R_v=None, extra=None, gate_chi2: float | None = None):
        """One GNSS fix in one update: position (states 0-2) and velocity (3-5), each gated
        on its own (`gate_chi2` is per 3 dof), plus `extra` = (H, innovation, R) rows that
        ride along ungated (the car's pseudo-measurements). Returns (pos_ok, vel_ok, dx)."""
        self.flush()
        PHt, S, nu = self._stack(nu_p, R_p, nu_v, R_v, extra)
        # a sub-vector's Mahalanobis distance is at most the whole's: when the whole passes
        # one block's gate, every block does (the usual case, one inversion)
        ok, _, dx = self._gated(PHt, S, nu, gate_chi2)
        if ok:
            return nu_p is not None, nu_v is not None, dx
        k = 0                                    # where the velocity rows start in S
        if nu_p is not None:
            if quadratic(inverse_small(S[0:3, 0:3]), nu_p) > gate_chi2:
                nu_p = None
            k = 3
        if nu_v is not None and quadratic(inverse_small(S[k:k + 3, k:k + 3]), nu_v) > gate_chi2:
            nu_v = None
        if nu_p is None and nu_v is None and extra is None:
            return False, False, None
        PHt, S, nu = self._stack(nu_p, R_p, nu_v, R_v, extra)
        return nu_p is not None, nu_v is not None, self._gated(PHt, S, nu, None)[2]

    def _stack(self, nu_p, R_p, nu_v, R_v, extra):
        """(P H^T, S, innovation) of the fix's rows stacked: position, velocity, extra."""
        blocks = []
        if nu_p is not None:
            blocks.append((_H_POS, nu_p, R_p))
        if nu_v is not None:
            blocks.append((_H_VEL, nu_v, R_v))
        if extra is not None:
            blocks.append(extra)
        H = np.concatenate([b[0] for b in blocks]) if len(blocks) > 1 else blocks[0][0]
        PHt = self.P @ H.T
        return PHt, H @ PHt + _block_diag([b[2] for b in blocks]), [v for b in blocks for v in b[1]]

    def _gated(self, PHt, S, innovation, gate_chi2):
        """The update proper: d2 = nu^T S^-1 nu; unless gated out, x += K nu and
        P -= K PHt^T with K = PHt S^-1 (P is symmetrised at a later flush)."""
        S_inv = _inverse(S)
        nu = np.asarray(innovation, float)
        w = S_inv @ nu
        d2 = float(nu @ w)
        if d2 - d2 != 0.0:
            raise Diverged("innovation is not finite")
        if gate_chi2 is not None and d2 > gate_chi2:
            return False, d2, None
        dx = (PHt @ w).tolist()
        self.P = self.P - PHt @ S_inv @ PHt.T
        x = self.x
        for i in range(N):
            x[i] += dx[i]
        return True, d2, dx

    def check(self) -> None:
        d = self.P.diagonal().tolist()
        total = sum(d) + sum(self.x)            # finite if and only if every term is
        if total - total != 0.0:
            raise Diverged("state or covariance not finite")
        if min(d) < -1e-9:
            raise Diverged("negative variance")
        if max(d[0], d[1], d[2]) > self.MAX_POS_VAR or max(d[3], d[4], d[5]) > self.MAX_VEL_VAR:
            raise Diverged("covariance blew up")


_H_POS = np.zeros((3, N))
_H_POS[:, P_] = np.eye(3)
_H_VEL = np.zeros((3, N))
_H_VEL[:, V_] = np.eye(3)


def inverse_small(S: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric 1x1, 2x2 or 3x3 matrix by cofactors, in plain floats:
    a tenth of np.linalg.inv's cost at this size. Diverged unless positive definite
    (leading minors > 0), as an innovation covariance must be."""
    n = S.shape[0]
    s = S.tolist()
    if n == 3:
        (a, b, c), (_, d, e), (_, _, f) = s
        A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
        det = a * A + b * B + c * C
        if not (det > 0.0 and det - det == 0.0 and a > 0.0 and a * d > b * b):
            raise Diverged("innovation covariance is not positive definite")
        k = 1.0 / det
        D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
        return np.array([[A * k, B * k, C * k], [B * k, D * k, E * k], [C * k, E * k, F * k]])
    if n == 2:
        (a, b), (_, d) = s
        det = a * d - b * b
        if not (det > 0.0 and det - det == 0.0 and a > 0.0):
            raise Diverged("innovation covariance is not positive definite")
        k = 1.0 / det
        return np.array([[d * k, -b * k], [-b * k, a * k]])
    if n == 1:
        if not (s[0][0] > 0.0 and s[0][0] - s[0][0] == 0.0):
            raise Diverged("innovation covariance is not positive definite")
        return np.array([[1.0 / s[0][0]]])
    try:
        return np.linalg.inv(S)
    except np.linalg.LinAlgError:
        raise Diverged("innovation covariance is singular") from None


def quadratic(M: np.ndarray, v) -> float:
    """v^T M v."""
    v = np.asarray(v, float)
    d2 = float(v @ M @ v)
    if d2 - d2 != 0.0:
        raise Diverged("innovation is not finite")
    return d2


def _inverse(S: np.ndarray) -> np.ndarray:
    if S.shape[0] <= 3:
        return inverse_small(S)
    try:
        S_inv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        raise Diverged("innovation covariance is singular") from None
    return S_inv


def _block_diag(blocks) -> np.ndarray:
    if len(blocks) == 1:
        return blocks[0]
    n = sum(b.shape[0] for b in blocks)
    out = np.zeros((n, n))
    k = 0
    for b in blocks:
        m = b.shape[0]
        out[k:k + m, k:k + m] = b
        k += m
    return out
