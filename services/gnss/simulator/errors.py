"""What makes a simulated GNSS fix wrong, and when the receiver has no fix at all.

Slow wander: the error sources of docs/sensors.md#gnss-error-budget, each a first-order
Gauss-Markov process (time-correlated, as real GNSS errors are: the ionosphere and the
orbits drift over tens of minutes, multipath over seconds, and even the receiver's noise
is smoothed over about a second: the car's 2016 fixes moved by centimetres, not decimetres,
from one epoch to the next). The table's "up to" figures set the sources' relative sizes.

A standalone receiver is more than that wander, and a filter that models its receiver as
a Gauss-Markov state plus a white share (the estimator does) would agree with a twin made
of the wander alone by construction. So the twin's default profile, `STANDALONE`, adds
what real receivers show and that model leaves out:

- jumps when the satellites in the solution change (the least-squares solution moves to
  another geometry: decimetres to a metre or two, part of it staying until the next
  change, part decaying as the receiver's smoothing settles), also when one satellite
  replaces another and the count stays the same; the car's 2016 drive: median 0.5 m,
  some of 5-8 m, at its 230 count changes;
- multipath bursts: a reflection the receiver locks on for a few seconds to tens of
  seconds, metres along one direction; more often when slow or parked (a moving antenna
  averages a reflection out, a still one does not: van Nee 1992);
- heavy tails: the per-fix part is Student-t (urban pseudorange errors are fitted by
  Student-t, logistic and Laplace laws, not Gaussian ones), and now and then a single fix
  is metres off (the 2016 drive: fix-to-fix kurtosis over 100);
- reported sigmas that follow the DOP (the satellite count) and are honest on average
  over a drive, not per fix: they know nothing of a burst;
- Doppler velocity errors of their own: white, Student-t, with rare spikes; not the
  positions' wander (the 2016 drive parked: 3 cm/s, kurtosis 9, lag-one correlation 0.1).

`GAUSS_MARKOV` (profile="gauss_markov") is the wander alone, the twin before issue 25, with
the same draws for a seed as then; benches compare against it. Either way the total is
scaled so the horizontal error has the receiver's circular error probable (1.8 m CEP for
the OEM4-G2L in single point, the car's own figure): for the wander alone, a circular
Gaussian, CEP = 1.1774 sigma per axis; the standalone profile's sizes are set at 1.8 m so
that the median over a drive is 1.8 m (tests/gnss/test_gnss_twin_errors.py) and scale with
the CEP.

One sky over two antennas: the satellite clocks, the orbits and the atmosphere are the
same for every receiver on the car (a metre apart, tracking the same satellites), so two
receivers' errors share them; multipath (each antenna's surroundings), receiver noise and
each receiver's satellite selection are its own. `CommonErrors` draws the shared part
once per car, on GPS time, and every receiver's `GnssErrorModel` given it scales it by its
own sizes.

Satellites and outages: the number of satellites in the solution wanders; now and then
(mean interval and durations from the car's 2016 drive: 12 outages of 0.2-3.1 s in 764 s)
the receiver loses its fix and reports INSUFFICIENT_OBS.
"""
from __future__ import annotations

import functools
import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

CEP_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))     # 1.1774
#: The CEP the standalone profile's sizes are given at (the OEM4-G2L's); they scale with it.
REFERENCE_CEP_M = 1.8


@dataclass(frozen=True)
class ErrorSource:
    name: str
    up_to_m: float          # the error budget's "up to" figure (docs/sensors.md#gnss-error-budget)
    tau_s: float            # correlation time; 0 = white
    common: bool            # the same for every receiver on the car (the signal's path)


#: The GNSS error budget (docs/sensors.md#gnss-error-budget) with correlation times typical of each
#: source. (The name keeps the guide's table number: see docs/README.md#glossary.)
SEED_TABLE_5_2 = (
    ErrorSource("satellite_clocks", 2.0, 1800.0, common=True),
    ErrorSource("orbit", 2.5, 3600.0, common=True),
    ErrorSource("ionosphere", 5.0, 1800.0, common=True),
    ErrorSource("troposphere", 0.5, 3600.0, common=True),
    ErrorSource("receiver_noise", 0.3, 1.0, common=False),     # after the code smoothing
    ErrorSource("multipath", 1.0, 20.0, common=False),
)


def _gauss_markov_step(z: np.ndarray, tau_s: tuple, dt_s: float,
                       rng: np.random.Generator) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov processes (one row per source, one column per
    axis) moved on by dt_s (Brown & Hwang: x' = a x + sqrt(1 - a^2) w, a = exp(-dt/tau))."""
    a, b = _gauss_markov_coefficients(tau_s, dt_s, z.shape[1])
    return a * z + b * rng.standard_normal(z.shape)


@functools.lru_cache(maxsize=64)
def _gauss_markov_coefficients(tau_s: tuple, dt_s: float, axes: int) -> tuple[np.ndarray, np.ndarray]:
    """a and sqrt(1 - a^2), each row repeated over `axes` columns (read-only). Remembered: the
    epochs are mostly the same time apart, and the exponentials cost more than the step; and
    whole rows, since numpy multiplies arrays of one shape twice as fast as it broadcasts."""
    tau = np.array(tau_s, float)
    white = tau <= 0.0
    a = np.where(white, 0.0, np.exp(-dt_s / np.where(white, 1.0, tau)))
    rows = np.repeat(a[:, None], axes, axis=1), np.repeat(np.sqrt(1.0 - a * a)[:, None], axes, axis=1)
    for r in rows:
        r.flags.writeable = False
    return rows


class CommonErrors:
    """The error sources every receiver on one car shares, as unit-variance processes on GPS
    time: `at(gps_ms)` is the same for every receiver asking about the same instant.

    The processes advance on a grid of `step_ms` (the twins' epochs are multiples of 50 ms)
    and the last `history_s` are kept, so receivers served from different threads, one a
    little behind the other, read the same values. Thread-safe.
    """

    def __init__(self, rng: np.random.Generator, sources=SEED_TABLE_5_2, step_ms: int = 50,
                 history_s: float = 60.0):
        self.rng = rng
        self.sources = tuple(s for s in sources if s.common)
        self.tau = tuple(s.tau_s for s in self.sources)
        self.step_ms = step_ms
        self._kept_steps = max(2, int(history_s * 1000 / step_ms))
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=self._kept_steps)
        self._lock = threading.Lock()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sources)

    def at(self, gps_ms: int) -> np.ndarray:
        """The shared processes (len(sources) x 3, unit variance) at the grid point of gps_ms."""
        k = int(round(gps_ms / self.step_ms))
        with self._lock:
            h = self._history
            if not h:
                h.append((k, self.rng.standard_normal((len(self.sources), 3))))
            elif k - h[-1][0] > self._kept_steps:
                # a long pause: one step across it, and the grid starts again there
                dt_s = (k - h[-1][0]) * self.step_ms / 1000.0
                z = _gauss_markov_step(h[-1][1], self.tau, dt_s, self.rng)
                h.clear()
                h.append((k, z))
            while h[-1][0] < k:
                z = _gauss_markov_step(h[-1][1], self.tau, self.step_ms / 1000.0, self.rng)
                h.append((h[-1][0] + 1, z))
            return h[max(0, k - h[0][0])][1]


@dataclass(frozen=True)
class ErrorProfile:
    """How a receiver's error behaves besides the slow wander of the sources.

    Position sizes are metres per horizontal axis at REFERENCE_CEP_M (vertical: times the
    vertical ratio) and scale with the receiver's CEP; velocity sizes are at
    REFERENCE_VELOCITY_SIGMA_MPS and scale with the receiver's velocity sigma. Intervals are
    the means of exponential waits; 0 = never. All defaults: the wander alone.
    """

    name: str
    wander_share: float = 1.0        # the wander's sigma, as a share of CEP / 1.1774
    white_sigma_m: float = 0.0       # Student-t error of each fix on its own ...
    white_dof: float = 3.0           # ... with these degrees of freedom
    offset_sigma_m: float = 0.0      # the satellite selection's own error, kept between changes
    offset_keep: float = 0.0         # its correlation across one change
    offset_dof: float = 4.0          # its steps are Student-t
    settle_kick_m: float = 0.0       # a change also kicks the solution (sigma) ...
    settle_tau_s: float = 8.0        # ... and the kick settles with this time constant
    swap_interval_s: float = 0.0     # one satellite replaced by another, the count unchanged
    burst_interval_parked_s: float = 0.0    # multipath bursts: mean wait when parked ...
    burst_interval_moving_s: float = 0.0    # ... and well under way,
    burst_speed_mps: float = 2.0            # going from one to the other over about this speed
    burst_duration_s: float = 6.0           # median length (log-normal) ...
    burst_duration_spread: float = 0.8      # ... and the sigma of its log
    burst_size_m: float = 1.8               # median horizontal size (log-normal) ...
    burst_size_spread: float = 0.5          # ... and the sigma of its log
    outlier_interval_s: float = 0.0  # a single fix metres off ...
    outlier_size_m: float = 5.0      # ... by about this much (median, 3D)
    velocity_dof: float = 0.0        # Doppler velocity noise: Student-t (0 = Gaussian) ...
    velocity_spike_interval_s: float = 0.0  # ... with now and then one velocity off
    velocity_spike_mps: float = 0.25        # by about this much (median, 3D)

    @property
    def wander_only(self) -> bool:
        """Nothing but the Gauss-Markov wander and a white Gaussian velocity error."""
        return self == ErrorProfile(self.name)


#: The twin before issue 25: the sources' Gauss-Markov wander alone (the filter's own model).
GAUSS_MARKOV = ErrorProfile("gauss_markov")
#: A standalone single-frequency receiver as real ones behave (module docstring,
#: docs/sensors.md#gnss-error-budget): the wander, plus steps at satellite changes, multipath
#: bursts, Student-t fix noise, outliers and Doppler spikes. Sizes give 1.8 m CEP over a drive.
STANDALONE = ErrorProfile(
    "standalone", wander_share=0.94, white_sigma_m=0.06, white_dof=3.0,
    offset_sigma_m=0.45, offset_keep=0.6, settle_kick_m=0.3, settle_tau_s=8.0, swap_interval_s=60.0,
    burst_interval_parked_s=60.0, burst_interval_moving_s=180.0, burst_speed_mps=2.0,
    burst_duration_s=6.0, burst_duration_spread=0.8, burst_size_m=1.8, burst_size_spread=0.5,
    outlier_interval_s=240.0, outlier_size_m=5.0,
    velocity_dof=5.0, velocity_spike_interval_s=60.0, velocity_spike_mps=0.2)
PROFILES = {p.name: p for p in (GAUSS_MARKOV, STANDALONE)}
#: The velocity sigma the profiles' velocity sizes are given at.
REFERENCE_VELOCITY_SIGMA_MPS = 0.03
#: What the reported sigmas assume of a drive: the count changes every 10 s (SkyModel), half
#: the time parked and half under way.
NOMINAL_CHANGE_INTERVAL_S = 10.0

#: 5 to 9 satellites, equally likely (SkyModel's default wander): the mean of 1 / (n - 3)
_MEAN_INVERSE_REDUNDANCY = sum(1.0 / (n - 3) for n in range(5, 10)) / 5


@functools.cache
def dop_factor(sats_used: int | None) -> float:
    """How the geometry of `sats_used` satellites scales a fix's error, relative to the sky's
    average: the DOP goes roughly as 1 / sqrt(n - 3), so 1.31 with 5 satellites, 0.76 with 9,
    and the mean of its square over 5-9 satellites is 1 (None: the average sky)."""
    if sats_used is None:
        return 1.0
    return 1.0 / math.sqrt(_MEAN_INVERSE_REDUNDANCY * (max(sats_used, 4) - 3))


def _unit_t(rng: np.random.Generator, dof: float, n: int = 3) -> np.ndarray:
    """Student-t draws of unit variance (dof > 2; 0: Gaussian)."""
    if dof <= 0.0:
        return rng.standard_normal(n)
    return rng.standard_t(dof, n) * math.sqrt((dof - 2.0) / dof)


def _direction(rng: np.random.Generator) -> np.ndarray:
    """A unit vector in a random direction in 3D."""
    v = rng.standard_normal(3)
    return v / max(1e-12, float(np.linalg.norm(v)))


def _happens(rng: np.random.Generator, dt_s: float, interval_s: float) -> bool:
    """Whether an event of mean wait `interval_s` comes in the next `dt_s` (a Poisson process)."""
    return interval_s > 0.0 and dt_s > 0.0 and rng.random() < -math.expm1(-dt_s / interval_s)


class SatelliteSelection:
    """The error of the satellites the solution uses: it steps when they change.

    A different set of satellites is a different least-squares geometry for the same range
    errors, so the position moves: `offset` is the selection's own error (kept until the next
    change, then partly redrawn), `settle` the kick a change gives the receiver's smoothing,
    decaying. Reference metres per axis.
    """

    def __init__(self, rng: np.random.Generator, profile: ErrorProfile):
        self.rng, self.p = rng, profile
        self.offset = profile.offset_sigma_m * _unit_t(rng, profile.offset_dof)
        self.settle = np.zeros(3)
        self.changes = 0
        self._sats: int | None = None

    def step(self, dt_s: float, sats_used: int | None, dop: float) -> np.ndarray:
        p, rng = self.p, self.rng
        if dt_s > 0.0:
            self.settle *= math.exp(-dt_s / p.settle_tau_s)
        changed = sats_used is not None and self._sats is not None and sats_used != self._sats
        changed = _happens(rng, dt_s, p.swap_interval_s) or changed
        if sats_used is not None:
            self._sats = sats_used
        if changed:
            keep = p.offset_keep
            self.offset = keep * self.offset + (math.sqrt(1.0 - keep * keep) * p.offset_sigma_m
                                                * _unit_t(rng, p.offset_dof))
            self.settle = self.settle + p.settle_kick_m * dop * rng.standard_normal(3)
            self.changes += 1
        return self.offset + self.settle


@dataclass
class Burst:
    """One multipath episode: a reflection the receiver tracks for a while."""

    start_s: float
    end_s: float
    ramp_s: float           # it grows and fades over this long
    vector: np.ndarray      # its full size and direction (reference metres, mostly horizontal)
    period_s: float         # the reflection's phase beats the size by +-WOBBLE over this period
    phase: float

    WOBBLE = 0.3

    def at(self, t_s: float) -> np.ndarray:
        edge = min(1.0, (t_s - self.start_s) / self.ramp_s, (self.end_s - t_s) / self.ramp_s)
        envelope = 0.5 * (1.0 - math.cos(math.pi * max(0.0, edge)))
        beat = 1.0 + self.WOBBLE * math.sin(2.0 * math.pi * (t_s - self.start_s) / self.period_s + self.phase)
        return (envelope * beat) * self.vector


class MultipathBursts:
    """Multipath episodes: onsets a Poisson process whose rate falls with speed (a moving
    antenna averages a reflection out, a still one keeps it), lengths and sizes log-normal,
    each along one direction. Reference metres per axis."""

    def __init__(self, rng: np.random.Generator, profile: ErrorProfile):
        self.rng, self.p = rng, profile
        self.active: list[Burst] = []
        self.started = 0
        self._begun = False

    def rate(self, speed_mps: float) -> float:
        """Onsets per second at `speed_mps`."""
        p = self.p
        parked = 1.0 / p.burst_interval_parked_s if p.burst_interval_parked_s > 0 else 0.0
        moving = 1.0 / p.burst_interval_moving_s if p.burst_interval_moving_s > 0 else 0.0
        return moving + (parked - moving) * math.exp(-abs(speed_mps) / p.burst_speed_mps)

    def mean_duration_s(self) -> float:
        return self.p.burst_duration_s * math.exp(0.5 * self.p.burst_duration_spread ** 2)

    def _new(self, t_s: float) -> Burst:
        p, rng = self.p, self.rng
        duration = min(90.0, max(1.5, p.burst_duration_s * math.exp(p.burst_duration_spread * rng.standard_normal())))
        size = p.burst_size_m * math.exp(p.burst_size_spread * rng.standard_normal())
        heading = rng.uniform(0.0, 2.0 * math.pi)
        vector = size * np.array([math.cos(heading), math.sin(heading), 0.5 * rng.standard_normal()])
        self.started += 1
        return Burst(t_s, t_s + duration, min(1.0, 0.25 * duration), vector,
                     float(rng.uniform(4.0, 15.0)), float(rng.uniform(0.0, 2.0 * math.pi)))

    def step(self, t_s: float, dt_s: float, speed_mps: float) -> np.ndarray:
        rng, rate = self.rng, self.rate(speed_mps)
        if not self._begun:
            # start as a drive already under way: in a burst as often as on average
            self._begun = True
            busy = rate * self.mean_duration_s()
            if rate > 0.0 and rng.random() < busy / (1.0 + busy):
                burst = self._new(t_s)
                shift = rng.uniform(0.0, burst.end_s - burst.start_s)
                burst.start_s -= shift
                burst.end_s -= shift
                self.active.append(burst)
        elif rate > 0.0 and _happens(rng, dt_s, 1.0 / rate):
            self.active.append(self._new(t_s))
        if not self.active:
            return _NOTHING
        self.active = [b for b in self.active if b.end_s > t_s]
        total = np.zeros(3)
        for b in self.active:
            total += b.at(t_s)
        return total


_NOTHING = np.zeros(3)
_NOTHING.flags.writeable = False


class StandaloneErrors:
    """What a standalone receiver's fixes have besides the wander (reference units: metres
    per axis for positions, velocity sigmas for velocities)."""

    def __init__(self, rng: np.random.Generator, profile: ErrorProfile):
        self.rng, self.p = rng, profile
        self.selection = SatelliteSelection(rng, profile)
        self.bursts = MultipathBursts(rng, profile)
        self.burst = np.zeros(3)        # the bursts' part of the latest position
        self.selection_part = np.zeros(3)   # the satellite selection's part of it
        self.outliers = 0
        self.velocity_spikes = 0

    def position(self, t_s: float, dt_s: float, sats_used: int | None, dop: float,
                 speed_mps: float) -> np.ndarray:
        p, rng = self.p, self.rng
        self.burst = self.bursts.step(t_s, dt_s, speed_mps)
        self.selection_part = self.selection.step(dt_s, sats_used, dop)
        error = self.selection_part + self.burst
        error += (p.white_sigma_m * dop) * _unit_t(rng, p.white_dof)
        if _happens(rng, dt_s, p.outlier_interval_s):
            self.outliers += 1
            error += p.outlier_size_m * math.exp(0.4 * rng.standard_normal()) * _direction(rng)
        return error

    def velocity(self, dt_s: float, dop: float) -> np.ndarray:
        p, rng = self.p, self.rng
        error = dop * _unit_t(rng, p.velocity_dof)
        if _happens(rng, dt_s, p.velocity_spike_interval_s):
            self.velocity_spikes += 1
            size = p.velocity_spike_mps / REFERENCE_VELOCITY_SIGMA_MPS
            error += size * math.exp(0.6 * rng.standard_normal()) * _direction(rng)
        return error

    def nominal_variance(self) -> float:
        """The mean square per horizontal axis (reference metres^2) these add over a drive as
        NOMINAL_CHANGE_INTERVAL_S assumes (outliers, a few fixes a drive, left out)."""
        p = self.p
        changes = 1.0 / NOMINAL_CHANGE_INTERVAL_S + (1.0 / p.swap_interval_s if p.swap_interval_s > 0 else 0.0)
        settle = changes * p.settle_kick_m ** 2 * 0.5 * p.settle_tau_s
        return p.offset_sigma_m ** 2 + settle + p.white_sigma_m ** 2 + self._burst_variance()

    def own_variance(self) -> float:
        """The part of `nominal_variance` that is the receiver's own (fix noise and multipath
        bursts): what differential corrections cannot remove (the selection's steps are the
        geometry of the sky's range errors, which they do remove)."""
        return self.p.white_sigma_m ** 2 + self._burst_variance()

    def _burst_variance(self) -> float:
        p, bursts = self.p, self.bursts
        rate = 0.5 * (bursts.rate(0.0) + bursts.rate(math.inf))
        energy = (bursts.mean_duration_s() - 1.25) * (1.0 + 0.5 * Burst.WOBBLE ** 2)
        size2 = p.burst_size_m ** 2 * math.exp(2.0 * p.burst_size_spread ** 2)
        return rate * energy * 0.5 * size2


class GnssErrorModel:
    """ENU position error (m) and velocity error (m/s) of a GNSS receiver over time.

    ``step(t_s, gps_ms, sky=, speed_mps=)`` advances the processes to time ``t_s`` (seconds,
    any origin, non-decreasing) and returns (position_error_enu, velocity_error_enu); with
    ``common`` (the car's CommonErrors) the shared sources are read at ``gps_ms`` instead of
    drawn here. The standalone profile reads the receiver's ``sky`` (a SkyModel) at ``t_s``
    for its satellite count, and bursts more often at low ``speed_mps``; ``sigma_enu`` and
    ``velocity_sigma`` are then what the receiver reports at that epoch.
    """

    def __init__(self, rng: np.random.Generator, cep_m: float = 1.8,
                 vertical_ratio: float = 1.6, velocity_sigma_mps: float = 0.03,
                 sources=SEED_TABLE_5_2, common: CommonErrors | None = None,
                 profile: str | ErrorProfile = "standalone"):
        self.rng = rng
        self.profile = PROFILES[profile] if isinstance(profile, str) else profile
        self.sources = tuple(sources)
        self._velocity_axes = np.array([1.0, 1.0, vertical_ratio]) * velocity_sigma_mps
        self.velocity_sigma = self._velocity_axes
        self.tau = tuple(s.tau_s for s in self.sources)
        self.common = common
        if common is not None:
            rows = [i for i, s in enumerate(self.sources) if s.common]
            if tuple(self.sources[i].name for i in rows) != common.names:
                raise ValueError("the receiver's common error sources are not the car's")
            # the rows the car's sky overwrites: a slice when they follow each other (as in the
            # budget's table), which numpy assigns several times faster than a list of rows
            together = rows and rows == list(range(rows[0], rows[-1] + 1))
            self._common_rows = slice(rows[0], rows[-1] + 1) if together else rows
        self._common_idx = [i for i, s in enumerate(self.sources) if s.common]
        self._own_idx = [i for i, s in enumerate(self.sources) if not s.common]
        self.extras = None if self.profile.wander_only else StandaloneErrors(rng, self.profile)
        self._dop = 1.0
        self.set_cep(cep_m, vertical_ratio)
        # start from the stationary distribution: the error is already fully grown
        self._z = rng.standard_normal((len(self.sources), 3))
        self._t: float | None = None

    def set_cep(self, cep_m: float, vertical_ratio: float | None = None) -> None:
        """Resize the error (e.g. when SBAS corrections start or stop being used)."""
        if vertical_ratio is not None:
            self.vertical_ratio = vertical_ratio
        axes = np.array([1.0, 1.0, self.vertical_ratio])
        weights = np.array([s.up_to_m for s in self.sources])
        scale = cep_m / CEP_PER_SIGMA * self.profile.wander_share / np.linalg.norm(weights)
        self._sigma = np.outer(weights * scale, axes)
        self._axes = cep_m / REFERENCE_CEP_M * axes
        wander = np.sum(self._sigma ** 2, axis=0)
        extra = 0.0 if self.extras is None else self.extras.nominal_variance()
        self._rms = np.sqrt(wander + extra * self._axes ** 2)
        self.cep_m = cep_m

    @property
    def sigma_enu(self) -> np.ndarray:
        """What the receiver reports as its position error's standard deviation along E, N, U:
        the error's RMS over a drive, scaled by the latest epoch's geometry (dop_factor)."""
        return self._dop * self._rms

    @property
    def dop(self) -> float:
        """The latest epoch's geometry factor (dop_factor of its satellite count)."""
        return self._dop

    def shares(self) -> tuple[np.ndarray, np.ndarray]:
        """The parts of the latest position error (ENU m) that differential corrections
        remove: the common sources' wander (the sky's: the same for every receiver near the
        base) and the satellite selection's steps (that sky seen through this geometry)."""
        rows = self._common_idx
        common = np.add.reduce(self._z[rows] * self._sigma[rows], axis=0)
        if self.extras is None:
            return common, np.zeros(3)
        return common, self._axes * self.extras.selection_part

    def common_rms(self) -> np.ndarray:
        """The common sources' RMS along E, N, U (m)."""
        return np.sqrt(np.sum(self._sigma[self._common_idx] ** 2, axis=0))

    def common_change_variance(self, age_s: float) -> np.ndarray:
        """The mean square along E, N, U (m^2) of how far the common sources move in `age_s`:
        each a Gauss-Markov process, 2 (1 - exp(-age / tau)) of its variance."""
        out = np.zeros(3)
        for i in self._common_idx:
            out += self._sigma[i] ** 2 * (-2.0 * math.expm1(-age_s / self.sources[i].tau_s))
        return out

    def own_variance(self) -> np.ndarray:
        """The mean square along E, N, U (m^2) of what is this receiver's own in its error
        (noise and multipath: wander, bursts, fix noise) at the average sky: what remains of it
        under differential corrections."""
        wander = np.sum(self._sigma[self._own_idx] ** 2, axis=0)
        extra = 0.0 if self.extras is None else self.extras.own_variance()
        return wander + extra * self._axes ** 2

    def step(self, t_s: float, gps_ms: int | None = None, *, sky: SkyModel | None = None,
             speed_mps: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        # the sky first: its draws come before the errors' (TruthSolver asks it again, unchanged);
        # the wander alone does not ask, so its draws keep the order of the twin before issue 25
        sats = None if self.extras is None or sky is None else sky.at(t_s).sats_used
        if dt > 0.0:
            self._z = _gauss_markov_step(self._z, self.tau, dt, self.rng)
        if self.common is not None:
            self._z[self._common_rows] = self.common.at(int(round(t_s * 1000)) if gps_ms is None else gps_ms)
        position = np.add.reduce(self._z * self._sigma, axis=0)        # .sum(axis=0) without its wrapper
        if self.extras is None:
            return position, self.rng.standard_normal(3) * self.velocity_sigma
        self._dop = dop_factor(sats)
        self.velocity_sigma = self._dop * self._velocity_axes
        position += self._axes * self.extras.position(t_s, dt, sats, self._dop, speed_mps)
        return position, self._velocity_axes * self.extras.velocity(dt, self._dop)


@dataclass
class SkyState:
    """What the receiver sees at one epoch."""

    sats_used: int
    sats_tracked: int
    outage: bool                # too few satellites for a fix


class SkyModel:
    """Satellites in the solution and outages (INSUFFICIENT_OBS periods).

    Outages come at random (exponential intervals, mean ``outage_interval_s``) and last
    ``outage_min_s`` plus an exponential part of mean ``outage_mean_s``; ``outages``
    adds fixed ones as (start_s, end_s) pairs, for tests and demos.
    """

    def __init__(self, rng: np.random.Generator, *, sats_range=(5, 9),
                 outage_interval_s: float = 64.0, outage_mean_s: float = 0.9,
                 outage_min_s: float = 0.2, outages=()):
        self.rng = rng
        self.sats_range = sats_range
        self.outage_interval_s = outage_interval_s
        self.outage_mean_s = outage_mean_s
        self.outage_min_s = outage_min_s
        self.fixed_outages = tuple(outages)
        self._sats = int(rng.integers(sats_range[0], sats_range[1] + 1))
        self._extra = int(rng.integers(0, 3))
        self._next_change: float | None = None
        self._outage_start: float | None = None
        self._outage_end = -math.inf

    def _draw_interval(self) -> float:
        if self.outage_interval_s <= 0:
            return math.inf
        return float(self.rng.exponential(self.outage_interval_s))

    def at(self, t_s: float) -> SkyState:
        """The sky at ``t_s`` (non-decreasing seconds since the receiver started)."""
        if self._next_change is None:
            self._next_change = t_s + float(self.rng.uniform(5.0, 15.0))
            self._outage_start = t_s + self._draw_interval()
        assert self._outage_start is not None, "drawn with the first change, at the first call"
        while t_s >= self._next_change:
            lo, hi = self.sats_range
            self._sats = int(np.clip(self._sats + self.rng.choice((-1, 1)), lo, hi))
            self._extra = int(self.rng.integers(0, 3))
            self._next_change += float(self.rng.uniform(5.0, 15.0))
        while t_s >= self._outage_start:
            self._outage_end = (self._outage_start + self.outage_min_s
                                + float(self.rng.exponential(self.outage_mean_s)))
            self._outage_start = self._outage_end + self._draw_interval()
        outage = t_s < self._outage_end or any(a <= t_s < b for a, b in self.fixed_outages)
        if outage:
            used = 3 if self._sats > 4 else 2
            return SkyState(used, used + self._extra, True)
        return SkyState(self._sats, self._sats + self._extra, False)
