"""What a MEMS IMU gets wrong beyond white noise, for the Razor's twin (docs/sensors.md#imu-error-model).

Per triad (gyro in deg/s, accelerometer in g), per axis:

- bias instability B: a sum of three first-order Gauss-Markov processes, time constants a
  decade apart (3, 30, 300 s), equal variances; their Allan deviation is flat within 4 %
  from 6 to 300 s at 0.664 B: a flicker floor, where a single random walk would rise;
- rate random walk K: a random walk of the bias, b += K sqrt(dt) w;
- turn-on bias: drawn once per run; the gyro's wandering part starts at zero (the firmware
  averages the gyro at boot and removes it), the accelerometer's anywhere in its spread;
- scale factor and misalignment: (I + S + M) applied to the true vector, S diagonal, M the
  six cross-axis terms, drawn once per run.

And vibration, as resonances shared by the six axes with their own amplitudes: the traction
motor's (on once the car moves, lines where the parked recordings with the motor running have
them, one at the motor's own frequency) and the road's (growing with speed), plus the motor's
broadband part. A resonance is a damped oscillator driven by noise (its line `width_hz` wide),
and the sensors see the rate of change of its motion: nothing at 0 Hz, so what vibration adds
to a rate or an acceleration integrates to a bounded angle or velocity, as a shaking body's
does, never to a drift.

These are deliberately not the estimator's model (a random-walk accelerometer bias and white
noise): a flicker bias, scale and misalignment the filter does not estimate, vibration lines.
Everything is drawn from the generator given to `start`, so a run is fixed by its seed.
"""
from __future__ import annotations

import functools
import math
import operator
from dataclasses import dataclass

import numpy as np

from viena.services.imu.model.allan import FLICKER_FLOOR

#: the Gauss-Markov time constants that make the bias-instability floor
GM_TIME_CONSTANTS_S = (10.0, 100.0, 1000.0)
#: the rate random walk meets the floor here when the data cannot tell K (an assumption)
RRW_CROSSING_S = 1000.0
#: the motor's vibration is full once the car moves this fast
ENGINE_FULL_MPS = 1.0
#: road vibration figures are given at this speed and scale with it
ROAD_REFERENCE_MPS = 10.0
#: the slow processes move this often (their time constants are 1 s and more)
SLOW_STEP_S = 0.1


def _gm_avar(tau: np.ndarray, t: float) -> np.ndarray:
    """Allan variance of a unit-variance Gauss-Markov process of time constant t
    (IEEE 952 C.1.6, with q_c^2 = 2 / t)."""
    x = tau / t
    return 2.0 * t / tau * (1.0 - (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * x))


@functools.lru_cache(maxsize=8)
def gm_sigma_per_b(time_constants: tuple) -> float:
    """Each process's standard deviation per unit B, so that the sum's Allan deviation
    averages 0.664 B between twice the shortest and the longest time constant."""
    tau = np.geomspace(2.0 * time_constants[0], time_constants[-1], 64)
    avar = sum(_gm_avar(tau, t) for t in time_constants)
    return FLICKER_FLOOR / math.sqrt(float(np.mean(avar)))


@dataclass(frozen=True)
class TriadErrors:
    """One sensor triad's slow errors, per axis x y z, in its unit u (deg/s or g)."""

    bias_instability: tuple = (0.0, 0.0, 0.0)       # B [u]
    rate_random_walk: tuple = (0.0, 0.0, 0.0)       # K [u / sqrt(s)]
    turn_on_bias: tuple = (0.0, 0.0, 0.0)           # 1 sigma [u], drawn per run
    scale_factor: float = 0.0                       # 1 sigma, drawn per axis and run
    misalignment_rad: float = 0.0                   # 1 sigma, each cross-axis term
    #: the wandering bias is zero at the start (removed at boot): the gyro with the VIENA firmware
    zero_at_start: bool = False


@dataclass(frozen=True)
class VibrationLine:
    """A vibration line: rms per axis at full strength, gyro [deg/s] and accel [g].

    hz + hz_per_mps * speed is its frequency as the board samples it (a line above the
    board's Nyquist frequency is given where it shows, aliased); `width_hz` its width (the
    resonance's, full width at half height).
    `source`: "engine" (full once moving, ENGINE_FULL_MPS) or "road" (rms scales with
    speed / ROAD_REFERENCE_MPS)."""

    hz: float
    width_hz: float
    gyro_dps: tuple
    accel_g: tuple
    source: str = "engine"
    hz_per_mps: float = 0.0


@functools.lru_cache(maxsize=256)
def resonator(hz: float, width_hz: float, dt: float) -> tuple[complex, float]:
    """One step of a resonance as a turning, decaying phasor: c_k = rho c_k-1 + s w_k with
    rho = r e^(i 2 pi hz dt), r = exp(-pi width dt) (a line `width_hz` wide) and w_k complex
    white of unit variance per part; s such that the step Re(c_k - c_k-1) has unit variance
    at this dt (E|c_k - c_k-1|^2 = s^2 (|rho - 1|^2 / (1 - r^2) + 1), half of it real).

    A phasor, not the AR(2) x_k = a1 x_k-1 + a2 x_k-2: the live twin's steps vary (10 or
    20 ms as the sim polls it), and an AR(2) whose coefficients switch from step to step
    while its state stays can grow without bound (it did: 1e38 g within 20 s at 2.6 m/s);
    the phasor only turns and shrinks, whatever the steps."""
    r = math.exp(-math.pi * width_hz * dt)
    rho = r * complex(math.cos(2.0 * math.pi * hz * dt), math.sin(2.0 * math.pi * hz * dt))
    s2 = 2.0 / (abs(rho - 1.0) ** 2 / (1.0 - r * r) + 1.0)
    return rho, math.sqrt(0.5 * s2)


@dataclass(frozen=True)
class ImuErrors:
    gyro: TriadErrors = TriadErrors()
    accel: TriadErrors = TriadErrors()
    lines: tuple = ()                                   # VibrationLine
    #: the motor's broadband vibration, white, rms per axis at full strength
    engine_white_gyro_dps: tuple = (0.0, 0.0, 0.0)
    engine_white_accel_g: tuple = (0.0, 0.0, 0.0)
    time_constants_s: tuple = GM_TIME_CONSTANTS_S

    def start(self, rng: np.random.Generator, t_s: float) -> ErrorState:
        """One run of a board: the per-run draws made, the processes at their start."""
        return ErrorState(self, rng, t_s)


NO_ERRORS = ImuErrors()


def _triad_matrix(e: TriadErrors, rng: np.random.Generator) -> np.ndarray:
    """I + S + M: scale factors on the diagonal, misalignments off it."""
    m = rng.normal(0.0, e.misalignment_rad, (3, 3)) if e.misalignment_rad else np.zeros((3, 3))
    s = rng.normal(0.0, e.scale_factor, 3) if e.scale_factor else np.zeros(3)
    np.fill_diagonal(m, s)
    return np.eye(3) + m


class _Normals:
    """Standard normals from the run's generator a block at a time: one call per thousands of
    samples, not several per sample (a generator call costs more than the arithmetic)."""

    def __init__(self, rng: np.random.Generator, block: int = 2048):
        self.rng, self.block = rng, block
        self.values: list[float] = []
        self.next = 0

    def take(self, n: int) -> int:
        """Where the next n values start in `values` (read it after this call: it may be a new block)."""
        if self.next + n > len(self.values):
            self.values = self.rng.standard_normal(max(self.block, n)).tolist()
            self.next = 0
        start = self.next
        self.next += n
        return start


class ErrorState:
    """The errors of one board over one run: `step(t_s, speed_mps)` gives this sample's
    gyro [deg/s] and accelerometer [g] errors (bias, vibration) as six floats; `gyro_matrix`
    and `accel_matrix` are this run's I + S + M.

    The bias's slow processes move every SLOW_STEP_S by the exact discrete step for the time
    gone, not every sample: the same statistics from a tenth of the work; vibration moves
    every sample. Python floats: numpy's per-call cost on 6-vectors is several times the
    arithmetic's."""

    def __init__(self, errors: ImuErrors, rng: np.random.Generator, t_s: float):
        self.errors, self.t_s = errors, float(t_s)
        g, a = errors.gyro, errors.accel
        self.gyro_matrix = _triad_matrix(g, rng)
        self.accel_matrix = _triad_matrix(a, rng)
        self._turn_on = [float(rng.normal(0.0, s)) if s else 0.0 for s in (*g.turn_on_bias, *a.turn_on_bias)]
        per_b = gm_sigma_per_b(tuple(errors.time_constants_s))
        self._gm_sigma = [b * per_b for b in (*g.bias_instability, *a.bias_instability)]
        self._rrw = [float(k) for k in (*g.rate_random_walk, *a.rate_random_walk)]
        n_gm = len(errors.time_constants_s)
        # per axis: the Gauss-Markov states, then the random walk; the gyro's start at zero if removed at boot
        self._bias = [[0.0 if (axis < 3 and g.zero_at_start) or not s else float(rng.normal(0.0, s))
                       for _ in range(n_gm)] + [0.0] for axis, s in enumerate(self._gm_sigma)]
        self._slow = any(self._gm_sigma) or any(self._rrw)
        self._offset = [t + sum(b) for t, b in zip(self._turn_on, self._bias)]
        self._lines = [(line.hz, line.hz_per_mps, line.width_hz, line.source == "engine") for line in errors.lines]
        #: per axis, each line's rms
        self._line_rms = [list(col) for col in zip(*([*line.gyro_dps, *line.accel_g] for line in errors.lines))]
        if not self._line_rms:
            self._line_rms = [[] for _ in range(6)]
        self._motion = [0j for _ in errors.lines]                 # each resonance's phasor
        #: per step length dt: dt as the resonators take it, and the fixed lines' resonators (None: moving)
        self._resonators: dict[float, tuple[float, list]] = {}
        self._white = [*errors.engine_white_gyro_dps, *errors.engine_white_accel_g]
        self._shakes = bool(self._lines) or any(self._white)
        self._normals = _Normals(rng)
        self._coefficients: dict[float, list] = {}
        self._since = 0.0
        self.dt = 0.0                       # the last step's length (s)

    def step(self, t_s: float, speed_mps: float) -> list[float]:
        """The six errors now: gyro x y z [deg/s], accel x y z [g]."""
        dt = min(max(t_s - self.t_s, 0.0), 1.0)
        self.t_s, self.dt = t_s, dt
        self._since += dt
        slow_step = self._since >= SLOW_STEP_S
        if slow_step and self._slow:
            self._wander(self._since)
        speed = abs(speed_mps)
        if speed > 0.0 and dt > 0.0 and self._shakes:
            out = self._vibrate(dt, speed)
        else:
            out = list(self._offset)
        if slow_step:
            self._since = 0.0
        return out

    def _wander(self, dt: float) -> None:
        """x <- a x + sqrt(1 - a^2) sigma w per Gauss-Markov process, b <- b + K sqrt(dt) w."""
        key = round(dt, 4)
        coefficients = self._coefficients.get(key)
        if coefficients is None:
            if len(self._coefficients) > 32:
                self._coefficients.clear()
            keep = [math.exp(-key / t) for t in self.errors.time_constants_s]
            coefficients = self._coefficients[key] = [
                (keep + [1.0], [s * math.sqrt(1.0 - k * k) for k in keep] + [w * math.sqrt(key)])
                for s, w in zip(self._gm_sigma, self._rrw)]
        n = len(self._bias[0])
        i = self._normals.take(6 * n)
        z = self._normals.values
        for axis, (states, (keep, drive)) in enumerate(zip(self._bias, coefficients)):
            total = 0.0
            for k in range(n):
                v = keep[k] * states[k] + drive[k] * z[i]
                states[k] = v
                total += v
                i += 1
            self._offset[axis] = self._turn_on[axis] + total

    def _vibrate(self, dt: float, speed: float) -> list[float]:
        engine = min(speed / ENGINE_FULL_MPS, 1.0)
        road = speed / ROAD_REFERENCE_MPS
        n = len(self._lines)
        i = self._normals.take(2 * n + 6)
        z = self._normals.values
        dt_key, fixed = self._resonators.get(dt) or self._resonators_for(dt)
        amps = []
        motion = self._motion
        for j, (hz, hz_per_mps, width, is_engine) in enumerate(self._lines):
            rho, sigma = fixed[j] or resonator(round(hz + hz_per_mps * speed, 1), width, dt_key)
            m = motion[j]
            # sigma w as complex(sigma re, sigma im): the same numbers as sigma * w, a float times a complex
            c = motion[j] = rho * m + complex(sigma * z[i], sigma * z[i + 1])
            i += 2
            amps.append((c.real - m.real) * (engine if is_engine else road))
        return [o + sum(map(operator.mul, amps, rms)) + engine * w * x
                for o, rms, w, x in zip(self._offset, self._line_rms, self._white, z[i:i + 6])]

    def _resonators_for(self, dt: float) -> tuple[float, list]:
        """dt to 0.1 us (the resonators' cache key) and the fixed lines' resonators, for steps of dt
        (the live twin's steps take a few values: 10 or 20 ms as the sim polls it)."""
        if len(self._resonators) > 32:
            self._resonators.clear()
        dt_key = round(dt, 7)
        step = self._resonators[dt] = (dt_key, [resonator(hz, width, dt_key) if not per_mps else None
                                                for hz, per_mps, width, _ in self._lines])
        return step
