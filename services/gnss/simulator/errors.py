"""What makes a simulated GNSS fix wrong, and when the receiver has no fix at all.

Position error: the sum of the error sources of seed table 5.2, each a first-order
Gauss-Markov process (time-correlated, as real GNSS errors are: the ionosphere and the
orbits drift over tens of minutes, multipath over seconds, and even the receiver's noise
is smoothed over about a second: the car's 2016 fixes moved by centimetres, not decimetres,
from one epoch to the next). The
table's "up to" figures set the sources' relative sizes; the total is scaled so the
horizontal error has the receiver's circular error probable (1.8 m CEP for the OEM4-G2L
in single point, seed §5.4). For a circular Gaussian, CEP = 1.1774 sigma per axis.

Satellites and outages: the number of satellites in the solution wanders; now and then
(mean interval and durations from the car's 2016 drive: 12 outages of 0.2-3.1 s in 764 s)
the receiver loses its fix and reports INSUFFICIENT_OBS.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CEP_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))     # 1.1774


@dataclass(frozen=True)
class ErrorSource:
    name: str
    up_to_m: float          # seed table 5.2
    tau_s: float            # correlation time; 0 = white


#: Seed table 5.2 with correlation times typical of each source.
SEED_TABLE_5_2 = (
    ErrorSource("satellite_clocks", 2.0, 1800.0),
    ErrorSource("orbit", 2.5, 3600.0),
    ErrorSource("ionosphere", 5.0, 1800.0),
    ErrorSource("troposphere", 0.5, 3600.0),
    ErrorSource("receiver_noise", 0.3, 1.0),      # after the receiver's code smoothing
    ErrorSource("multipath", 1.0, 20.0),
)


class GnssErrorModel:
    """ENU position error (m) and velocity error (m/s) of a GNSS receiver over time.

    ``step(t_s)`` advances the processes to time ``t_s`` (seconds, any origin,
    non-decreasing) and returns (position_error_enu, velocity_error_enu).
    """

    def __init__(self, rng: np.random.Generator, cep_m: float = 1.8,
                 vertical_ratio: float = 1.6, velocity_sigma_mps: float = 0.03,
                 sources=SEED_TABLE_5_2):
        self.rng = rng
        self.sources = tuple(sources)
        self.velocity_sigma = np.array([1.0, 1.0, vertical_ratio]) * velocity_sigma_mps
        weights = np.array([s.up_to_m for s in self.sources])
        self.tau = np.array([s.tau_s for s in self.sources])
        self.set_cep(cep_m, vertical_ratio)
        # start from the stationary distribution: the error is already fully grown
        self._state = rng.standard_normal((len(self.sources), 3)) * self._sigma
        self._weights = weights
        self._t: float | None = None

    def set_cep(self, cep_m: float, vertical_ratio: float | None = None) -> None:
        """Resize the error (e.g. when SBAS corrections start or stop being used)."""
        if vertical_ratio is not None:
            self.vertical_ratio = vertical_ratio
        weights = np.array([s.up_to_m for s in self.sources])
        sigma_h = cep_m / CEP_PER_SIGMA
        scale = sigma_h / np.linalg.norm(weights)
        per_axis = np.array([1.0, 1.0, self.vertical_ratio])
        new_sigma = np.outer(weights * scale, per_axis)
        if hasattr(self, "_sigma"):
            self._state *= new_sigma / self._sigma
        self._sigma = new_sigma
        self.cep_m = cep_m

    @property
    def sigma_enu(self) -> np.ndarray:
        """Standard deviation of the total position error along E, N, U."""
        return np.sqrt(np.sum(self._sigma ** 2, axis=0))

    def step(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        if dt > 0.0:
            white = self.tau <= 0.0
            a = np.where(white, 0.0, np.exp(-dt / np.where(white, 1.0, self.tau)))
            noise = self.rng.standard_normal(self._state.shape)
            self._state = (a[:, None] * self._state
                           + np.sqrt(1.0 - a * a)[:, None] * self._sigma * noise)
        velocity = self.rng.standard_normal(3) * self.velocity_sigma
        return self._state.sum(axis=0), velocity


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
