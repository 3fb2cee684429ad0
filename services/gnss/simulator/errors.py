"""What makes a simulated GNSS fix wrong, and when the receiver has no fix at all.

Position error: the sum of the error sources of docs/sensors.md#gnss-error-budget, each a first-order
Gauss-Markov process (time-correlated, as real GNSS errors are: the ionosphere and the
orbits drift over tens of minutes, multipath over seconds, and even the receiver's noise
is smoothed over about a second: the car's 2016 fixes moved by centimetres, not decimetres,
from one epoch to the next). The
table's "up to" figures set the sources' relative sizes; the total is scaled so the
horizontal error has the receiver's circular error probable (1.8 m CEP for the OEM4-G2L
in single point, the car's own figure). For a circular Gaussian, CEP = 1.1774 sigma per axis.

One sky over two antennas: the satellite clocks, the orbits and the atmosphere are the
same for every receiver on the car (a metre apart, tracking the same satellites), so two
receivers' errors share them; only multipath (each antenna's surroundings) and receiver
noise are each its own. `CommonErrors` draws the shared part once per car, on GPS time,
and every receiver's `GnssErrorModel` given it scales it by its own sizes.

Satellites and outages: the number of satellites in the solution wanders; now and then
(mean interval and durations from the car's 2016 drive: 12 outages of 0.2-3.1 s in 764 s)
the receiver loses its fix and reports INSUFFICIENT_OBS.
"""
from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

CEP_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))     # 1.1774


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


def _gauss_markov_step(z: np.ndarray, tau_s: np.ndarray, dt_s: float,
                       rng: np.random.Generator) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov processes (one row per source, one column per
    axis) moved on by dt_s (Brown & Hwang: x' = a x + sqrt(1 - a^2) w, a = exp(-dt/tau))."""
    white = tau_s <= 0.0
    a = np.where(white, 0.0, np.exp(-dt_s / np.where(white, 1.0, tau_s)))
    return a[:, None] * z + np.sqrt(1.0 - a * a)[:, None] * rng.standard_normal(z.shape)


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
        self.tau = np.array([s.tau_s for s in self.sources])
        self.step_ms = step_ms
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=max(2, int(history_s * 1000 / step_ms)))
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
            elif k - h[-1][0] > h.maxlen:
                # a long pause: one step across it, and the grid starts again there
                dt_s = (k - h[-1][0]) * self.step_ms / 1000.0
                z = _gauss_markov_step(h[-1][1], self.tau, dt_s, self.rng)
                h.clear()
                h.append((k, z))
            while h[-1][0] < k:
                z = _gauss_markov_step(h[-1][1], self.tau, self.step_ms / 1000.0, self.rng)
                h.append((h[-1][0] + 1, z))
            return h[max(0, k - h[0][0])][1]


class GnssErrorModel:
    """ENU position error (m) and velocity error (m/s) of a GNSS receiver over time.

    ``step(t_s, gps_ms)`` advances the processes to time ``t_s`` (seconds, any origin,
    non-decreasing) and returns (position_error_enu, velocity_error_enu); with ``common``
    (the car's CommonErrors) the shared sources are read at ``gps_ms`` instead of drawn here.
    """

    def __init__(self, rng: np.random.Generator, cep_m: float = 1.8,
                 vertical_ratio: float = 1.6, velocity_sigma_mps: float = 0.03,
                 sources=SEED_TABLE_5_2, common: CommonErrors | None = None):
        self.rng = rng
        self.sources = tuple(sources)
        self.velocity_sigma = np.array([1.0, 1.0, vertical_ratio]) * velocity_sigma_mps
        self.tau = np.array([s.tau_s for s in self.sources])
        self.common = common
        if common is not None:
            self._common_rows = [i for i, s in enumerate(self.sources) if s.common]
            if tuple(self.sources[i].name for i in self._common_rows) != common.names:
                raise ValueError("the receiver's common error sources are not the car's")
        self.set_cep(cep_m, vertical_ratio)
        # start from the stationary distribution: the error is already fully grown
        self._z = rng.standard_normal((len(self.sources), 3))
        self._t: float | None = None

    def set_cep(self, cep_m: float, vertical_ratio: float | None = None) -> None:
        """Resize the error (e.g. when SBAS corrections start or stop being used)."""
        if vertical_ratio is not None:
            self.vertical_ratio = vertical_ratio
        weights = np.array([s.up_to_m for s in self.sources])
        scale = cep_m / CEP_PER_SIGMA / np.linalg.norm(weights)
        self._sigma = np.outer(weights * scale, [1.0, 1.0, self.vertical_ratio])
        self.cep_m = cep_m

    @property
    def sigma_enu(self) -> np.ndarray:
        """Standard deviation of the total position error along E, N, U."""
        return np.sqrt(np.sum(self._sigma ** 2, axis=0))

    def step(self, t_s: float, gps_ms: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        if dt > 0.0:
            self._z = _gauss_markov_step(self._z, self.tau, dt, self.rng)
        if self.common is not None:
            self._z[self._common_rows] = self.common.at(int(round(t_s * 1000)) if gps_ms is None else gps_ms)
        velocity = self.rng.standard_normal(3) * self.velocity_sigma
        return (self._z * self._sigma).sum(axis=0), velocity


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
