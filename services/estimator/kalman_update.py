"""The Kalman filter's measurement updates (kalman.py holds its state and prediction).

A measurement is its innovation nu = z - H x, its covariance R and its rows H (or the
first state it measures directly); the filter applies it: x += K nu, P -= K S K^T, each
block gated on its Mahalanobis distance (docs/estimator.md#innovation-gate). GNSS
position and velocity go in one stacked update with the car's pseudo-measurements
riding along (`update_fix`).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from viena.services.estimator.kalman import KalmanNoise

#: the core states: position, velocity, accelerometer bias
P_, V_, B_ = slice(0, 3), slice(3, 6), slice(6, 9)
#: the tilt error states, when there are any
T_ = slice(9, 11)
_I3 = np.eye(3)


class Diverged(Exception):
    """The covariance blew up or a number stopped being finite."""


class KalmanUpdates:
    """The updates of `NavKalman`: `x` a list of `n` floats, `P` an n x n array, the
    receivers' error blocks past the `core` states."""

    n: int
    core: int
    x: list[float]
    P: np.ndarray
    receivers: dict[str, int]
    _h_cache: dict[tuple, np.ndarray]
    noise: KalmanNoise

    def flush(self) -> None:
        """Move the covariance to now (NavKalman's)."""
        raise NotImplementedError

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

    def update_fix(self, nu_p, R_p, nu_v=None, R_v=None, extra=None, gate_chi2: float | None = None,
                   unit: str | None = None):
        """One GNSS fix of `unit` in one update: position (p plus the receiver's error) and
        velocity, each gated on its own (`gate_chi2` is per 3 dof), plus `extra` = (H,
        innovation, R) rows that ride along ungated (the car's pseudo-measurements).
        Returns (pos_ok, vel_ok, dx, d2_pos, d2_vel): the blocks' NIS (nan when absent)."""
        self.flush()
        k = self.receivers.get(unit) if unit is not None else None
        PHt, S, nu = self._stack(nu_p, R_p, nu_v, R_v, extra, k)
        j = 3 if nu_p is not None else 0         # where the velocity rows start in S
        d2p = quadratic(inverse_small(S[0:3, 0:3]), nu_p) if nu_p is not None else math.nan
        d2v = quadratic(inverse_small(S[j:j + 3, j:j + 3]), nu_v) if nu_v is not None else math.nan
        gate = math.inf if gate_chi2 is None else gate_chi2
        if nu_p is not None and d2p > gate:
            nu_p = None
        if nu_v is not None and d2v > gate:
            nu_v = None
        if nu_p is None and nu_v is None and extra is None:
            return False, False, None, d2p, d2v
        if not (d2p > gate or d2v > gate):        # nothing refused: the stack as it is
            dx = self._gated(PHt, S, nu, None)[2]
        else:
            PHt, S, nu = self._stack(nu_p, R_p, nu_v, R_v, extra, k)
            dx = self._gated(PHt, S, nu, None)[2]
        return nu_p is not None, nu_v is not None, dx, d2p, d2v

    def inflate(self, first: int, nu) -> None:
        """The filter refused this block's measurements again and again: it is less sure
        than it thought. Its covariance grows by the disagreement (nu nu^T; consistency.py)."""
        self.flush()
        v = np.asarray(nu, float)
        sl = slice(first, first + len(v))
        self.P[sl, sl] += np.outer(v, v)

    def position_innovation_cov(self, R_p, unit: str | None = None) -> np.ndarray:
        """S of a position fix of `unit` with covariance R_p, as of now."""
        self.flush()
        H = self._h_pos(self.receivers.get(unit) if unit is not None else None)
        return H @ self.P @ H.T + R_p

    def _h_pos(self, k) -> np.ndarray:
        """The rows of a fix's position (p plus receiver k's error, when k is not None)."""
        return self._rows("position", k)

    def _rows(self, kind: str, k=None) -> np.ndarray:
        """The constant H rows of a position or velocity, made once per state size: read-only
        (building them for every fix cost more than the update's arithmetic)."""
        key = (kind, self.n, k)
        H = self._h_cache.get(key)
        if H is None:
            H = np.zeros((3, self.n))
            H[:, P_ if kind == "position" else V_] = _I3
            if k is not None:
                H[:, k:k + 3] = _I3
            H.flags.writeable = False
            self._h_cache[key] = H
        return H

    def _stack(self, nu_p, R_p, nu_v, R_v, extra, k):
        """(P H^T, S, innovation) of the fix's rows stacked: position, velocity, extra."""
        blocks = []
        if nu_p is not None:
            blocks.append((self._h_pos(k), nu_p, R_p))
        if nu_v is not None:
            blocks.append((self._rows("velocity"), nu_v, R_v))
        if extra is not None:
            blocks.append(extra)
        H = np.concatenate([b[0] for b in blocks]) if len(blocks) > 1 else blocks[0][0]
        PHt = self.P @ H.T
        return PHt, H @ PHt + _block_diag([b[2] for b in blocks]), [v for b in blocks for v in b[1]]

    def _gated(self, PHt, S, innovation, gate_chi2):
        """The update proper: d2 = nu^T S^-1 nu; unless gated out, x += K nu and
        P -= K PHt^T with K = PHt S^-1 (P is symmetrised at a later flush).

        With consider states (the receivers' errors, `gnss_consider`) their rows of K are
        zero (Schmidt 1966): the gain is no longer the optimal one for the whole state, so
        the covariance takes the general form P - K PHt^T - PHt K^T + K S K^T."""
        S_inv = _inverse(S)
        nu = np.asarray(innovation, float)
        w = S_inv @ nu
        d2 = float(nu @ w)
        if d2 - d2 != 0.0:
            raise Diverged("innovation is not finite")
        if gate_chi2 is not None and d2 > gate_chi2:
            return False, d2, None
        if self.receivers and self.noise.gnss_consider:
            K = PHt @ S_inv
            K[self.core:, :] = 0.0
            dx = (K @ nu).tolist()
            KPH = K @ PHt.T
            self.P = self.P - KPH - KPH.T + K @ S @ K.T
        else:
            dx = (PHt @ w).tolist()
            self.P = self.P - PHt @ S_inv @ PHt.T
        x = self.x
        for i in range(self.n):
            x[i] += dx[i]
        return True, d2, dx



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
