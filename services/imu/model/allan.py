"""Allan deviation of an inertial sensor's rate series, and the noise terms read from it
(IEEE Std 952-1997 annex C, IEEE Std 1554-2005; docs/sensors.md#imu-noise-figures). numpy only.

The deviation is the overlapping estimator (NIST SP 1065 eq. 11) at octave-spaced averaging
times tau = m tau0, m = 1, 2, 4, ...; its confidence the usual one from the number of
independent clusters K = floor(n / m): sigma_err / sigma = 1 / sqrt(2 (K - 1)) (IEEE 952 C.3).

For a rate in unit u (deg/s, g), the terms and their Allan variance (IEEE 952 table C.2):

    Q  quantization           u s        3 Q^2 / tau^2        slope -1
    N  angle/velocity RW      u sqrt(s)  N^2 / tau            slope -1/2, N = sigma(1 s)
    B  bias instability       u          (2 ln 2 / pi) B^2    flat, B = floor / 0.664
    K  rate random walk       u / sqrt(s)  K^2 tau / 3        slope +1/2, K = sigma(3 s)

The fit is the regression on the whole curve (Jurado et al. 2019; the model imu_utils fits):
the variance is linear in Q^2, N^2, B^2, K^2, so a weighted non-negative least squares in
relative terms (each point weighted by its confidence) finds them together, where reading
one line at a time lets a neighbouring term bend it. A term is given only where the curve
shows it: it must carry most of the model's variance over an octave at least, where the
curve has enough clusters; otherwise the fit says why not (and, for B, the bound the curve
does set).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

#: the terms, in the order of the fit's columns
TERMS = ("quantization", "random_walk", "bias_instability", "rate_random_walk")
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)      # 0.664: the flat floor is 0.664 B
#: a figure is read only from points with at least this many independent clusters (35 %)
MIN_CLUSTERS = 5
#: a curve shallower than this at the shortest taus is the sensor's own low-pass, not a term
BAND_LIMITED_SLOPE = -0.4
#: no point is trusted to better than this in the fit: the four terms are idealisations no real
#: curve follows more closely, and without it the many clusters at short tau outvote the floor
MODEL_ERROR = 0.05


def _basis(tau: np.ndarray) -> np.ndarray:
    """Allan variance of Q, N, B, K = 1 at each tau: columns in TERMS order."""
    tau = np.asarray(tau, float)
    return np.column_stack([3.0 / tau ** 2, 1.0 / tau, np.full_like(tau, FLICKER_FLOOR ** 2), tau / 3.0])


@dataclass(frozen=True)
class AllanCurve:
    """sigma(tau) of one axis: tau [s], the deviation [u], the independent clusters behind it."""

    tau_s: np.ndarray
    adev: np.ndarray
    clusters: np.ndarray

    @property
    def rel_error(self) -> np.ndarray:
        """1 sigma relative error of each point: 1 / sqrt(2 (K - 1))."""
        return 1.0 / np.sqrt(2.0 * np.maximum(self.clusters - 1, 1))

    @property
    def lower(self) -> np.ndarray:
        return self.adev * (1.0 - self.rel_error).clip(0.0)

    @property
    def upper(self) -> np.ndarray:
        return self.adev * (1.0 + self.rel_error)


def octave_factors(n: int, per_octave: int = 1) -> np.ndarray:
    """Cluster sizes m = 2^(k / per_octave) up to m <= (n - 1) / 2 (two clusters at least)."""
    if n < 3:
        return np.zeros(0, int)
    top = math.log2((n - 1) / 2)
    m = np.round(2.0 ** (np.arange(0.0, top + 1e-9, 1.0 / per_octave))).astype(int)
    return np.unique(m[m >= 1])


def allan_deviation(rate: np.ndarray, sample_rate_hz: float, per_octave: int = 1) -> AllanCurve:
    """Overlapping Allan deviation of evenly sampled rates (one axis) at octave-spaced tau."""
    y = np.asarray(rate, float)
    if y.ndim != 1:
        raise ValueError("one axis at a time")
    n = len(y)
    tau0 = 1.0 / sample_rate_hz
    # the integrated series (angle, velocity): x_k = tau0 sum y_<k, n + 1 points
    x = np.concatenate([[0.0], np.cumsum(y - y.mean())]) * tau0
    ms = octave_factors(n, per_octave)
    adev = np.empty(len(ms))
    for i, m in enumerate(ms):
        d = x[2 * m:] - 2.0 * x[m:-m] + x[:-2 * m]
        adev[i] = math.sqrt(float(np.mean(d * d)) / (2.0 * (m * tau0) ** 2))
    return AllanCurve(ms * tau0, adev, n // ms)


def pooled(curves: list[AllanCurve]) -> AllanCurve:
    """Several recordings of one sensor (each its own run) as one curve: at each cluster size
    the variances averaged, weighted by their degrees of freedom K - 1; the clusters add up.
    The curves must come from the same cluster sizes (octaves from m = 1): the shorter
    ones' missing long taus are left out there."""
    longest = max(curves, key=lambda c: len(c.tau_s))
    tau = np.zeros(len(longest.tau_s))
    var = np.zeros_like(tau)
    dof = np.zeros_like(tau)
    clusters = np.zeros(len(tau), int)
    for c in curves:
        k = len(c.tau_s)
        w = np.maximum(c.clusters - 1, 1).astype(float)
        var[:k] += w * c.adev ** 2
        tau[:k] += w * c.tau_s
        dof[:k] += w
        clusters[:k] += c.clusters
    return AllanCurve(tau / dof, np.sqrt(var / dof), clusters)


@dataclass(frozen=True)
class NoiseTerms:
    """The IEEE 952 terms of one axis, in the rate's unit u (None: the curve does not show it)."""

    quantization: float | None = None          # Q [u s]
    random_walk: float | None = None           # N [u sqrt(s)]: sigma at tau = 1 s on the -1/2 line
    bias_instability: float | None = None      # B [u]: the flat floor / 0.664
    rate_random_walk: float | None = None      # K [u / sqrt(s)]: sigma at tau = 3 s on the +1/2 line
    #: what the curve does say about B when it has no floor: its lowest point (upper 1 sigma) / 0.664
    bias_instability_at_most: float | None = None
    #: where the fitted curve is lowest (within the data), s
    floor_tau_s: float | None = None
    #: the regression's own values, every term, seen or not (for plotting the model)
    model: tuple = (0.0, 0.0, 0.0, 0.0)
    why_not: dict = field(default_factory=dict)     # term -> why it is not given

    def model_adev(self, tau_s) -> np.ndarray:
        return np.sqrt(_basis(np.atleast_1d(tau_s)) @ (np.array(self.model) ** 2))


def _nnls(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """min |a c - b| with c >= 0, for a handful of columns: every active set, the best
    feasible one (exact, and 16 small solves for four terms)."""
    best, best_cost = np.zeros(a.shape[1]), float(b @ b)
    for k in range(1, a.shape[1] + 1):
        for cols in itertools.combinations(range(a.shape[1]), k):
            sol, *_ = np.linalg.lstsq(a[:, cols], b, rcond=None)
            if np.any(sol < 0):
                continue
            c = np.zeros(a.shape[1])
            c[list(cols)] = sol
            r = a @ c - b
            cost = float(r @ r)
            if cost < best_cost:
                best, best_cost = c, cost
    return best


def band_limited_taus(curve: AllanCurve, until_s: float = 1.0) -> int:
    """How many of the shortest taus to leave out: those where the curve falls more slowly
    than white noise would (slope above -0.4), up to `until_s` at most. A chip's low-pass
    (the ITG-3200's 10 Hz) correlates the samples there; none of the IEEE terms describes
    that, and fitting it would pull N below the -1/2 line the rest of the curve follows."""
    slope = np.diff(np.log(curve.adev)) / np.diff(np.log(curve.tau_s))
    k = 0
    while k < len(slope) and slope[k] > BAND_LIMITED_SLOPE and curve.tau_s[k + 1] <= until_s:
        k += 1
    return k


def fit_terms(curve: AllanCurve, min_clusters: int = MIN_CLUSTERS) -> NoiseTerms:
    """Q, N, B, K of one axis from its Allan curve (module docstring), leaving out its
    band-limited start (band_limited_taus). A term that does not carry most of the variance
    over an octave at least where the curve is solid (min_clusters) cannot be told from its
    neighbours: it is dropped and the rest fitted again, so that it does not bend them."""
    use = curve.clusters >= 2
    use[:band_limited_taus(curve)] = False
    tau, adev = curve.tau_s[use], curve.adev[use]
    if len(tau) < 3 or np.any(adev <= 0):
        reason = "too few averaging times" if len(tau) < 3 else "the series is constant"
        return NoiseTerms(why_not={t: reason for t in TERMS})
    weight = 1.0 / (2.0 * np.maximum(curve.rel_error[use], MODEL_ERROR))   # the variance's is twice
    basis = _basis(tau)
    a = basis / (adev ** 2)[:, None] * weight[:, None]
    solid = curve.clusters[use] >= min_clusters
    cols = list(range(len(TERMS)))
    while True:
        c2 = np.zeros(len(TERMS))
        c2[cols] = _nnls(a[:, cols], weight)
        parts = basis * c2                               # each term's variance at each tau
        share = parts / np.maximum(parts.sum(axis=1, keepdims=True), 1e-300)
        seen = [j for j in cols if c2[j] > 0 and np.count_nonzero((share[:, j] >= 0.5) & solid) >= 2]
        if seen == cols or not seen:
            break
        cols = seen
    coef = np.sqrt(c2)
    model = tuple(float(c) for c in coef)
    values = {TERMS[j]: float(coef[j]) for j in seen}
    longest = float(tau[solid].max()) if solid.any() else 0.0
    why = {t: _why_not(t, longest, min_clusters) for t in TERMS if t not in values}
    at_most = floor_tau = None
    if "bias_instability" in values:
        grid = np.geomspace(tau[0], tau[-1], 200)
        floor_tau = float(grid[np.argmin(_basis(grid) @ c2)])
    elif solid.any():
        at_most = float(curve.upper[use][solid].min() / FLICKER_FLOOR)
    return NoiseTerms(values.get("quantization"), values.get("random_walk"), values.get("bias_instability"),
                      values.get("rate_random_walk"), at_most, floor_tau, model, why)


def _why_not(term: str, longest_s: float, min_clusters: int) -> str:
    if term == "quantization":
        return "no slope -1 at the shortest averaging times"
    if term == "random_walk":
        return "no slope -1/2 part"
    if term == "bias_instability":
        return (f"no flat floor up to tau = {longest_s:.3g} s (the longest with {min_clusters} clusters); "
                "a MEMS part's floor lies at tens to hundreds of seconds: record ten times that")
    return (f"no slope +1/2 part up to tau = {longest_s:.3g} s; rate random walk shows beyond the floor, "
            "in recordings of an hour or more")

