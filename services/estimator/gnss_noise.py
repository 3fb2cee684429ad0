"""How much of a receiver's error is white, seen from its own fixes.

A receiver's sigma says how wrong a fix may be, not how that error moves: a standalone
receiver's error wanders over minutes (orbits, clocks, the atmosphere, see
docs/sensors.md#gnss-error-budget), an RTK or a simulated white one jumps from fix to
fix. Averaging fixes helps with the second and not at all with the first, so the Kalman
filter splits each fix's variance: a white part, used as the fix's own noise, and a
wandering part, the receiver's error state (kalman.py).

The split is learnt. From one fix to the next the wandering part barely moves, and the
IMU knows how the antenna moved, so half the square of (change of the fix - change of
the antenna by the IMU) is the white variance. Its ratio to the reported variance,
averaged over the last `AVERAGE_FIXES` fixes, horizontally and vertically, is the white
share; until fixes have shown it, the setting `gnss_white_fraction` stands in.
(An innovation-based estimate of the measurement noise, after Mehra 1970 and Groves 2013
ch. 3 "adaptive Kalman filter", taken on time differences so the wandering part drops out.)

The split belongs to a kind of solution, not to a receiver: a receiver with corrections is
another receiver. One share per receiver and kind (`SOLUTION_KINDS`), each learnt from that
kind's fixes only; and the carrier-phase kinds (`CARRIER_KINDS`) are not learnt at all
(`carrier_share`): their white part is their noise, the floor of their sigma (millimetres
to centimetres), and whatever a receiver reports beyond it moves slowly: a float solution
converging, an RTK solution extrapolating corrections that stopped coming (its error grows
by centimetres a second), a long baseline's share. A fixed solution with fresh corrections
is then all white, with nothing left to wander: the receiver's error state does not follow
it. No average over a spell of such fixes would learn that.
"""
from __future__ import annotations

from typing import Any

#: the solution kinds whose split is known from their sigma, not learnt
CARRIER_KINDS = ("float", "fixed")


def carrier_share(var: float, white_sigma: float | None) -> float:
    """The white share of a carrier-phase fix's variance `var` (m^2) whose white noise is
    `white_sigma` (m; None: unknown, all of it)."""
    if white_sigma is None or var <= 0.0:
        return 1.0
    return min(1.0, white_sigma * white_sigma / var)

#: the share is an average over about this many fix-to-fix differences
AVERAGE_FIXES = 200
#: a share is never taken as less: no receiver is perfectly smooth, and a white part keeps
#: a fix handled late (against the trajectory's past, its correction applied now) from
#: swinging the split between the position and the receiver's error ...
MIN_SHARE = 0.1
#: ... and one difference never counts as more than this (one wild fix is not a share)
MAX_RATIO = 4.0
#: fixes further apart than this say little about the white part
MAX_GAP_NS = 1_500_000_000


class WhiteShare:
    """The white share of one receiver's variance: `horizontal` and `vertical`; `learns`
    False: a carrier-phase kind's, known from each fix (`carrier_share`), not learnt."""

    def __init__(self, prior: float, learns: bool = True):
        self.learns = learns
        self.horizontal = self.vertical = max(MIN_SHARE, min(1.0, prior))
        self.n = 0
        self._last: tuple[int, Any, Any] | None = None   # (t, fix ENU, antenna ENU by the IMU alone)

    @classmethod
    def of_kind(cls, kind: str, prior: float) -> WhiteShare:
        """The share for a receiver's fixes of this solution kind: learnt from the `prior`
        (the setting `gnss_white_fraction`), or known for a carrier-phase kind."""
        return cls(1.0, learns=False) if kind in CARRIER_KINDS else cls(prior)

    def forget(self) -> None:
        """The IMU's trajectory was cut (a reset, a spell without IMU): start the pairs again."""
        self._last = None

    def observe(self, t: int, z, antenna, var_e: float, var_n: float, var_u: float) -> None:
        """A fix at t: its ENU position `z`, the antenna's position `antenna` on the
        trajectory the IMU moved (corrections left out), and its variances along E, N, U."""
        if not self.learns:
            return
        last, self._last = self._last, (t, z, antenna)
        if last is None or not 0 < t - last[0] <= MAX_GAP_NS:
            return
        _, z0, a0 = last
        de = (z[0] - z0[0]) - (antenna[0] - a0[0])
        dn = (z[1] - z0[1]) - (antenna[1] - a0[1])
        du = (z[2] - z0[2]) - (antenna[2] - a0[2])
        rh = min(MAX_RATIO, 0.25 * (de * de + dn * dn) / (0.5 * (var_e + var_n)))
        rv = min(MAX_RATIO, 0.5 * du * du / var_u)
        self.n += 1
        k = 1.0 / min(self.n, AVERAGE_FIXES)
        # the prior counts as one difference, so a first lucky one does not decide
        if self.n == 1:
            k = 0.5
        self.horizontal = max(MIN_SHARE, min(1.0, self.horizontal + k * (rh - self.horizontal)))
        self.vertical = max(MIN_SHARE, min(1.0, self.vertical + k * (rv - self.vertical)))
