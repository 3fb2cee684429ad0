"""Least-squares fits behind `viena calibrate imu` (docs/sensors.md#imu-calibration), numpy only.

- accelerometer: six resting poses, one straight line per axis, LSB = gain * a[g] + offset
  (docs/sensors.md#accelerometer-six-position-fit; the manufacturer's method, cross-axis
  terms neglected);
- gyro: the mean of a still period is the bias (docs/sensors.md#gyro-bias);
- magnetometer, a car turning in circles: the field traces an ellipse in the XY plane;
  its centre is the hard-iron offset and its shape gives C^-1 = R_cal S R_cal^T
  (docs/sensors.md#magnetometer-2-d-ellipse), with z left alone: a car turns about z only;
- magnetometer, data spanning 3-D: a full ellipsoid, C^-1 its symmetric square root;
- any fit over a drive: a block bootstrap for its uncertainty (`block_weights`).

Every fit checks that the data can support it and raises FitError saying why not.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

AXES = "xyz"
POSES = ("+x", "-x", "+y", "-y", "+z", "-z")


class FitError(ValueError):
    """The data cannot give this calibration (too few points, degenerate shape, moving)."""


# -- uncertainty of a fit over a drive -------------------------------------------------------
def block_weights(t_sets: list[np.ndarray], block_s: float, replicates: int = 200,
                  seed: int = 0) -> tuple[list[np.ndarray], int]:
    """A block bootstrap's weights: the drive cut into blocks of block_s, each replicate
    drawing as many blocks with replacement, every point weighted by how often its block
    was drawn (replicates x points, one matrix per set of times, all drawn alike), and the
    number of blocks. Blocks, not points, because the errors of neighbouring points (a
    road's slope, a receiver's wander) are alike: resampling points would call a drive
    sure of what one stretch of road says many times over."""
    t0 = min(float(np.min(t)) for t in t_sets)
    index = [np.floor((np.asarray(t, float) - t0) / block_s).astype(int) for t in t_sets]
    names = np.unique(np.concatenate(index))
    drawn = np.random.default_rng(seed).integers(0, len(names), (replicates, len(names)))
    counts = np.zeros((replicates, len(names)))
    np.add.at(counts, (np.arange(replicates)[:, None], drawn), 1.0)
    return [counts[:, np.searchsorted(names, ix)] for ix in index], len(names)


def bootstrap_sigma(values: np.ndarray, blocks: int, axis: int = 0) -> np.ndarray:
    """The spread of bootstrap replicates, widened for few blocks (the bootstrap's variance
    is low by (blocks - 1) / blocks)."""
    return np.std(values, axis=axis, ddof=1) * math.sqrt(blocks / max(blocks - 1, 1))


# -- finding still periods --------------------------------------------------------------------
def still_segments(values: np.ndarray, window: int, max_std: float, min_len: int) -> list[slice]:
    """Runs of samples where every column's moving standard deviation stays below max_std."""
    values = np.asarray(values, float)
    n = len(values)
    if n < window:
        return []
    csum = np.cumsum(np.vstack([np.zeros(values.shape[1]), values]), axis=0)
    csq = np.cumsum(np.vstack([np.zeros(values.shape[1]), values ** 2]), axis=0)
    mean = (csum[window:] - csum[:-window]) / window
    var = (csq[window:] - csq[:-window]) / window - mean ** 2
    quiet = np.all(var <= max_std ** 2, axis=1)          # window starting at i is quiet
    still = np.zeros(n, bool)
    for first in np.flatnonzero(quiet):
        still[first:first + window] = True
    segments, start = [], None
    for i, s in enumerate(np.append(still, False)):
        if s and start is None:
            start = i
        elif not s and start is not None:
            if i - start >= min_len:
                segments.append(slice(start, i))
            start = None
    return segments


# -- accelerometer --------------------------------------------------------------------------
def classify_pose(mean_g) -> str | None:
    """'+z' if the board rests z up, ...; None if no axis is clearly along gravity."""
    mean_g = np.asarray(mean_g, float)
    norm = np.linalg.norm(mean_g)
    if not 0.5 < norm < 1.5:
        return None
    axis = int(np.argmax(np.abs(mean_g)))
    if abs(mean_g[axis]) / norm < 0.94:                 # more than ~20 deg off the axis
        return None
    return ("+" if mean_g[axis] > 0 else "-") + AXES[axis]


@dataclass(frozen=True)
class AccelFit:
    """Per axis: LSB = gain * a[g] + offset. Residuals are per pose and axis, in g."""

    gain_lsb_per_g: tuple
    offset_lsb: tuple
    residual_g: dict            # pose -> [3] measured minus model, in g
    rms_residual_g: tuple
    samples: dict               # pose -> number of samples averaged


def fit_six_position(pose_means_lsb: dict[str, np.ndarray], samples: dict | None = None) -> AccelFit:
    """Fit each axis's line through the six pose means (all six: at +1 g, -1 g and four
    times at 0 g for each axis), in least squares, with residuals."""
    missing = [p for p in POSES if p not in pose_means_lsb]
    if missing:
        raise FitError(f"six-position fit needs all six poses; missing {', '.join(missing)}")
    lsb = np.array([np.asarray(pose_means_lsb[p], float) for p in POSES])       # 6 x 3
    truth = np.zeros((6, 3))
    for k, pose in enumerate(POSES):
        truth[k, AXES.index(pose[1])] = 1.0 if pose[0] == "+" else -1.0
    gains, offsets, residuals = [], [], np.zeros((6, 3))
    for axis in range(3):
        design = np.column_stack([truth[:, axis], np.ones(6)])
        (gain, offset), *_ = np.linalg.lstsq(design, lsb[:, axis], rcond=None)
        if not gain > 0:
            raise FitError(f"{AXES[axis]} axis: gain {gain:.3g} LSB/g is not positive "
                           f"(poses swapped or board not turned over?)")
        gains.append(float(gain))
        offsets.append(float(offset))
        residuals[:, axis] = (lsb[:, axis] - design @ (gain, offset)) / gain
    rms = np.sqrt(np.mean(residuals ** 2, axis=0))
    return AccelFit(tuple(gains), tuple(offsets),
                    {p: tuple(residuals[k]) for k, p in enumerate(POSES)},
                    tuple(float(r) for r in rms), dict(samples or {}))


# -- gyro ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GyroBiasFit:
    bias_dps: tuple
    std_dps: tuple
    samples: int


def fit_gyro_bias(gyro_dps: np.ndarray, max_std_dps: float = 0.5, min_samples: int = 80) -> GyroBiasFit:
    """The mean rate over a still period; refuses data that is short or moving."""
    g = np.asarray(gyro_dps, float)
    if g.ndim != 2 or g.shape[1] != 3 or len(g) < min_samples:
        raise FitError(f"gyro bias needs at least {min_samples} still samples, got {len(g)}")
    std = g.std(axis=0)
    if np.any(std > max_std_dps):
        raise FitError(f"the board was not still: rate std {np.round(std, 3).tolist()} deg/s "
                       f"(limit {max_std_dps})")
    return GyroBiasFit(tuple(float(v) for v in g.mean(axis=0)), tuple(float(v) for v in std), len(g))


# -- magnetometer: 2-D ellipse (docs/sensors.md#magnetometer-2-d-ellipse) ----------------------
@dataclass(frozen=True)
class Ellipse:
    x0: float
    y0: float
    semi_major: float
    semi_minor: float
    alpha_rad: float            # angle from +x to the semi-major axis, in [0, pi)

    @property
    def axis_ratio(self) -> float:
        return self.semi_minor / self.semi_major


def fit_ellipse(x, y, min_points: int = 20, min_coverage: float = 0.5) -> Ellipse:
    """Direct least-squares ellipse (Fitzgibbon, in Halir & Flusser's stable form) on
    centred, scaled data; refuses too few points, an arc too short, or a non-ellipse."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < min_points:
        raise FitError(f"ellipse fit needs at least {min_points} points, got {len(x)}")
    mx, my = x.mean(), y.mean()
    scale = max(x.std(), y.std())
    if not scale > 0:
        raise FitError("all points are the same: the car did not turn")
    u, v = (x - mx) / scale, (y - my) / scale
    d1 = np.column_stack([u * u, u * v, v * v])
    d2 = np.column_stack([u, v, np.ones_like(u)])
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        raise FitError("points are collinear: no ellipse") from None
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])
    _, vecs = np.linalg.eig(m)
    vecs = np.real(vecs)
    cond = 4 * vecs[0] * vecs[2] - vecs[1] ** 2
    if np.count_nonzero(cond > 0) != 1:
        raise FitError("the points do not lie on an ellipse")
    a1 = vecs[:, cond > 0][:, 0]
    a, b, c, d, e, f = np.concatenate([a1, t @ a1])
    # centre and axes of  a u^2 + b uv + c v^2 + d u + e v + f = 0
    q = np.array([[a, b / 2], [b / 2, c]])
    try:
        uc, vc = np.linalg.solve(2 * q, [-d, -e])
    except np.linalg.LinAlgError:
        raise FitError("degenerate ellipse (a parabola or lines)") from None
    fc = a * uc * uc + b * uc * vc + c * vc * vc + d * uc + e * vc + f
    lam, vec = np.linalg.eigh(q)
    if not (np.all(lam * -fc > 0)):
        raise FitError("degenerate ellipse (imaginary axes)")
    axes = np.sqrt(-fc / lam) * scale            # eigh sorts ascending: major axis first
    major_dir = vec[:, 0]
    alpha = math.atan2(major_dir[1], major_dir[0]) % math.pi
    ell = Ellipse(float(mx + uc * scale), float(my + vc * scale), float(axes[0]), float(axes[1]),
                  float(alpha))
    if ell.axis_ratio < 0.2:
        raise FitError(f"ellipse too flat (axis ratio {ell.axis_ratio:.2f}): not a drive in circles")
    coverage = angular_coverage(x - ell.x0, y - ell.y0)
    if coverage < min_coverage:
        raise FitError(f"the points cover only {coverage:.0%} of the circle "
                       f"(need {min_coverage:.0%}): drive at least one full turn")
    return ell


def angular_coverage(dx, dy, bins: int = 36) -> float:
    """Fraction of 10-degree sectors around the centre that hold at least one point."""
    angles = np.arctan2(dy, dx)
    hist, _ = np.histogram(angles, bins=bins, range=(-math.pi, math.pi))
    return float(np.count_nonzero(hist)) / bins


def rotation_z(alpha: float) -> np.ndarray:
    """R_cal, the turn from +x to the ellipse's major axis (docs/sensors.md#magnetometer-2-d-ellipse)."""
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ellipse_c_inv(alpha: float, axis_ratio: float) -> np.ndarray:
    """C^-1 = R_cal S R_cal^T, S = diag(semi-minor/semi-major, 1, 1) (docs/sensors.md#magnetometer-2-d-ellipse)."""
    r = rotation_z(alpha)
    return r @ np.diag([axis_ratio, 1.0, 1.0]) @ r.T


@dataclass(frozen=True)
class MagFit:
    """H_c = C_inv (H_s - offset), in the units of the data."""

    method: str                 # "ellipse-2d" or "ellipsoid-3d"
    offset: tuple
    c_inv: tuple                # 3 x 3, row-major
    rms_residual: float         # spread of |H_c| (xy for 2-D) about its mean, data units
    radius: float               # mean |H_c| (xy for 2-D)
    ellipse: Ellipse | None = None
    info: dict = field(default_factory=dict)


def _check_radius(radius: float, min_radius: float | None, what: str) -> None:
    if min_radius is not None and radius < min_radius:
        raise FitError(f"the fitted {what} has radius {radius:.3g}, the Earth's field should give "
                       f"at least {min_radius:.3g}: the data do not go round (did the car turn?)")


def fit_mag_ellipse(mag: np.ndarray, min_radius: float | None = None, **kwargs) -> MagFit:
    """The 2-D method (docs/sensors.md#magnetometer-2-d-ellipse): ellipse in XY, z untouched
    (offset 0, scale 1). `min_radius`
    (data units) refuses a fit to noise around one heading."""
    mag = np.asarray(mag, float)
    ell = fit_ellipse(mag[:, 0], mag[:, 1], **kwargs)
    _check_radius(ell.semi_minor, min_radius, "ellipse")
    c_inv = ellipse_c_inv(ell.alpha_rad, ell.axis_ratio)
    offset = np.array([ell.x0, ell.y0, 0.0])
    corrected = (mag - offset) @ c_inv.T
    r = np.hypot(corrected[:, 0], corrected[:, 1])
    return MagFit("ellipse-2d", tuple(offset.tolist()), _rows(c_inv), float(r.std()), float(r.mean()), ell,
                  {"alpha_deg": math.degrees(ell.alpha_rad), "axis_ratio": ell.axis_ratio,
                   "semi_major": ell.semi_major, "semi_minor": ell.semi_minor,
                   "r_cal": _rows(rotation_z(ell.alpha_rad))})


# -- magnetometer: 3-D ellipsoid -------------------------------------------------------------
def span_ratio(points: np.ndarray) -> float:
    """Smallest over largest spread of the points' principal directions: ~0 for a plane."""
    p = np.asarray(points, float)
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def fit_mag_ellipsoid(mag: np.ndarray, min_points: int = 50, min_span: float = 0.2,
                      radius: float | None = None, min_radius: float | None = None) -> MagFit:
    """Quadric x'Mx + 2g'x = 1 by least squares; centre c = -M^-1 g; C_inv the symmetric
    square root of the normalised M, scaled so |H_c| keeps the data's mean radius (or
    `radius`, e.g. the known field in the data's units)."""
    p = np.asarray(mag, float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < min_points:
        raise FitError(f"ellipsoid fit needs at least {min_points} points, got {len(p)}")
    span = span_ratio(p)
    if span < min_span:
        raise FitError(f"the points do not span 3-D (span ratio {span:.2f} < {min_span}): "
                       f"use the 2-D ellipse method")
    mean = p.mean(axis=0)
    scale = p.std(axis=0).max()
    u = (p - mean) / scale
    x, y, z = u.T
    design = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z])
    v, *_ = np.linalg.lstsq(design, np.ones(len(u)), rcond=None)
    m = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    g = v[6:9]
    try:
        centre = -np.linalg.solve(m, g)
    except np.linalg.LinAlgError:
        raise FitError("degenerate ellipsoid") from None
    k = 1.0 + centre @ m @ centre
    shape = m / k
    lam, vec = np.linalg.eigh(shape)
    if not np.all(lam > 0):
        raise FitError("the points do not lie on an ellipsoid")
    _check_radius(float(scale / np.sqrt(lam.max())), min_radius, "ellipsoid")
    root = vec @ np.diag(np.sqrt(lam)) @ vec.T               # maps the ellipsoid to the unit sphere
    offset = mean + centre * scale
    unit = (p - offset) @ (root / scale).T
    target = radius if radius is not None else float(np.prod(1 / np.sqrt(lam)) ** (1 / 3) * scale)
    c_inv = root / scale * target
    r = np.linalg.norm((p - offset) @ c_inv.T, axis=1)
    return MagFit("ellipsoid-3d", tuple(offset.tolist()), _rows(c_inv), float(r.std()), float(r.mean()),
                  None, {"span_ratio": span, "radii": sorted((1 / np.sqrt(lam) * scale).tolist()),
                         "unit_sphere_rms": float(np.linalg.norm(unit, axis=1).std())})


def fit_mag(mag: np.ndarray, method: str = "auto", min_radius_2d: float | None = None,
            min_radius_3d: float | None = None) -> MagFit:
    """'auto': the 3-D ellipsoid when the data span 3-D, else the 2-D ellipse
    (docs/sensors.md#magnetometer-3-d-ellipsoid).
    The minimum radii (data units) keep noise around one heading from passing as a fit."""
    if method == "auto":
        method = "ellipsoid-3d" if span_ratio(mag) >= 0.2 else "ellipse-2d"
    if method == "ellipse-2d":
        return fit_mag_ellipse(mag, min_radius=min_radius_2d)
    if method == "ellipsoid-3d":
        return fit_mag_ellipsoid(mag, min_radius=min_radius_3d)
    raise ValueError(f"unknown magnetometer method {method!r}")


def _rows(m: np.ndarray) -> tuple:
    return tuple(tuple(float(v) for v in row) for row in np.asarray(m))
