"""How wrong a receiver's differential solutions are, type by type, and the sigmas it reports.

The estimator models a receiver as a white part plus a Gauss-Markov wander; a twin made of
that would agree with it by construction. So each type is built from the single-point
error the receiver already has (errors.py: the sky's sources shared by the car, its own
noise, multipath and satellite selection) and from what corrections change in it:

- PSRDIFF (vol. 1 §6.3.3: differential positioning removes "most of the biases caused by
  satellite clock error, ionospheric and tropospheric delays (for baselines less than
  50 km), and ephemeris prediction errors. However, the biases caused by multipath
  reception and receiver clock offset are uncorrelated between receivers"): the receiver's
  own noise, multipath and bursts stay; the sky's part and the selection's steps go; the
  base's own code noise and multipath come in (`DGPS_BASE_SIGMA_M`, shared by every rover
  of that base); what is left of the sky grows with the baseline (`DGPS_PPM`: ephemeris
  0.75 cm and troposphere 1 cm per 10 km, vol. 1 §6.5.1.3, plus the L1 ionosphere's
  decorrelation) and with the corrections' age (the sky's sources move on meanwhile).
- float (L1_FLOAT, NARROW_FLOAT): leaves the code solution within seconds and converges,
  with a slow wobble of its own, from decimetres towards centimetres: RT-20 as vol. 1
  Table 17 (kinematic: 45-25 cm CEP over the first 600 s, 25-5 cm by 3000 s), RT-2 faster.
- fixed (NARROW_INT): centimetres, white-ish plus a few millimetres of multipath, plus the
  baseline's share (vol. 1 Table 15, kinematic: 2 cm + 0.5 ppm to 10 km, 8 cm at 15 km,
  10 cm at 25 km); a wrong fix adds its offset while it lasts (rtk.py).
- the low-latency solution extrapolates the base's observations: its error grows with the
  differential age at vol. 1 Table 11's rates (CEP 1 cm/s to 2 s, 2 cm/s to 7 s, 5 cm/s
  to 30 s), the same for every rover of the base.

So a transition is a real step (single to PSRDIFF moves the position by the sky's error),
and two receivers on one car see the same base and the same sky: the common part removed,
the base's noise and the extrapolation are the same for both. The reported sigmas follow
the type (their mean squares over a drive), honest on average and not per fix, as the
single-point ones (errors.py).
"""
from __future__ import annotations

import math
import weakref
import zlib

import numpy as np

from .errors import CEP_PER_SIGMA, CommonErrors, ErrorSource, GnssErrorModel
from .rtk import RT20, RtkStatus

#: The base's own code noise and multipath in its corrections, m per horizontal axis.
DGPS_BASE_SIGMA_M = 0.2
#: What is left of the sky's errors per metre of baseline under code corrections (per axis):
#: ephemeris and troposphere 1.75 ppm (vol. 1 §6.5.1.3) + L1 ionosphere 4 ppm.
DGPS_PPM = 5.75e-6
#: RT-2 fixed: white and multipath (m per horizontal axis), the multipath's correlation time.
FIXED_WHITE_M = 0.010
FIXED_MULTIPATH_M = 0.006
FIXED_MULTIPATH_TAU_S = 10.0
#: A carrier solution's height error to its horizontal one (vol. 2 §3.4.3's example: 1.7).
RTK_VERTICAL_RATIO = 1.7
#: The float solution: its own wobble's correlation time, and how fast it leaves the code one.
FLOAT_WOBBLE_TAU_S = 30.0
FLOAT_LEAVE_TAU_S = {"RT-2": 8.0, "RT-20": 30.0}
#: float wobble size a + b exp(-t / tau), m per horizontal axis, by engine: RT-20 from vol. 1
#: Table 17 (kinematic; CEP = 1.18 sigma): 0.38 at the start, 0.21 at 600 s, 0.05 at 3000 s.
FLOAT_SIZE = {"RT-2": (0.03, 0.25, 60.0), "RT-20": (0.04, 0.34, 900.0)}
#: The base's processes, shared by every rover of one base: its code noise and multipath,
#: and the error of extrapolating its observations. Unit variance; sized here.
BASE_SOURCES = (ErrorSource("base_code", 1.0, 20.0, common=True),
                ErrorSource("extrapolation", 1.0, 30.0, common=True))


def rtk_baseline_sigma_m(baseline_m: float, engine: str) -> float:
    """A carrier solution's error from the baseline, m per horizontal axis: RT-2 1 ppm to
    10 km and 3 ppm more beyond (vol. 1 Table 15: 8 cm at 15 km, 10 cm at 25 km, with the
    fixed noise); RT-20 0.5, 0.75, 1.0 cm/km CEP at 0-10, 10-20, 20-50 km (Table 17)."""
    km = baseline_m / 1000.0
    if engine == RT20:
        cep = 0.005 * min(km, 10.0) + 0.0075 * min(max(km - 10.0, 0.0), 10.0) + 0.010 * max(km - 20.0, 0.0)
        return cep / CEP_PER_SIGMA
    return 1e-6 * baseline_m + 3e-6 * max(0.0, baseline_m - 10_000.0)


def extrapolation_sigma_m(age_s: float) -> float:
    """The low-latency solution's extrapolation error after `age_s` without a base
    observation, m per horizontal axis (vol. 1 Table 11, CEP rates 1, 2, 5 cm/s)."""
    a = max(0.0, age_s)
    cep = 0.01 * min(a, 2.0) + 0.02 * min(max(a - 2.0, 0.0), 5.0) + 0.05 * max(a - 7.0, 0.0)
    return cep / CEP_PER_SIGMA


#: the bases' processes, per car sky (or per receiver without one), per base ID
_BASES: weakref.WeakKeyDictionary[object, dict[str, CommonErrors]] = weakref.WeakKeyDictionary()


def base_processes(owner: object, base_id: str, entropy) -> CommonErrors:
    """The processes of base `base_id` as every receiver sharing `owner` (the car's sky)
    sees them, made on first use from `entropy` and the base's ID."""
    bases = _BASES.setdefault(owner, {})
    if base_id not in bases:
        seq = np.random.SeedSequence(entropy, spawn_key=(zlib.crc32(b"base"), zlib.crc32(base_id.encode())))
        bases[base_id] = CommonErrors(np.random.default_rng(seq), sources=BASE_SOURCES)
    return bases[base_id]


def _sky_entropy(sky: CommonErrors):
    seq = getattr(sky.rng.bit_generator, "seed_seq", None)
    return getattr(seq, "entropy", None)


class DifferentialErrors:
    """One receiver's error under corrections: ``step(status, gps_ms, single_error_enu)``
    after its GnssErrorModel stepped, returning (error ENU, sigma ENU) in metres, or None
    when the status is not differential (the single-point error and sigmas stand)."""

    def __init__(self, errors: GnssErrorModel, *, seed: int = 0, engine: str = "RT-2"):
        self.errors = errors
        self.engine = engine
        self.rng = np.random.default_rng([seed, zlib.crc32(b"differential")])
        sky = errors.common
        self._owner = sky if sky is not None else self
        self._entropy = _sky_entropy(sky) if sky is not None else [seed]
        self._vertical = np.array([1.0, 1.0, errors.vertical_ratio])
        self._rtk_axes = np.array([1.0, 1.0, RTK_VERTICAL_RATIO])
        self._wobble = self.rng.standard_normal(3)
        self._multipath = self.rng.standard_normal(3)
        self._t: float | None = None
        self._epoch: float | None = None            # the corrections' epoch the snapshot is of
        self._common_then = np.zeros(3)              # the sky's part at that epoch
        self._sizes: tuple | None = None            # (cep, common RMS, own variance) of the receiver's model

    def _receiver_sizes(self) -> tuple[np.ndarray, np.ndarray]:
        """The receiver's common RMS and own variance along E, N, U (they change with its CEP)."""
        errors = self.errors
        if self._sizes is None or self._sizes[0] != errors.cep_m:
            self._sizes = (errors.cep_m, np.maximum(errors.common_rms(), 1e-9), errors.own_variance())
        return self._sizes[1], self._sizes[2]

    def step(self, status: RtkStatus, gps_ms: int, single: np.ndarray | None):
        if status.phase not in ("dgps", "float", "fixed"):
            self._epoch = None
            return None
        assert single is not None, "a differential status comes with the single-point error"
        t = gps_ms / 1000.0
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        common, selection = self.errors.shares()
        epoch = t - status.diff_age_s
        if self._epoch is None or abs(epoch - self._epoch) > 1e-6:
            self._epoch, self._common_then = epoch, common
        base = base_processes(self._owner, status.base_id, self._entropy).at(gps_ms)
        c_rms, own_var = self._receiver_sizes()
        dgps, dgps_var = self._dgps(status, single, common, selection, base[0], c_rms, own_var)
        if status.phase == "dgps":
            return dgps, self._sigma(dgps_var)
        self._wobble = _gauss_markov(self._wobble, dt, FLOAT_WOBBLE_TAU_S, self.rng)
        self._multipath = _gauss_markov(self._multipath, dt, FIXED_MULTIPATH_TAU_S, self.rng)
        engine = RT20 if not status.l2 else self.engine
        resid_size = rtk_baseline_sigma_m(status.baseline_m, engine)
        ext_size = extrapolation_sigma_m(status.diff_age_s)
        # the baseline's share follows the sky (shared by the car's receivers), the
        # extrapolation the base's model of its observations (shared too)
        carrier = (resid_size * common / c_rms + ext_size * base[1]) * self._rtk_axes
        carrier_var = (resid_size ** 2 + ext_size ** 2) * self._rtk_axes ** 2
        if status.phase == "float":
            w = math.exp(-status.convergence_s / FLOAT_LEAVE_TAU_S[engine])
            a, b, tau = FLOAT_SIZE[engine]
            size = a + b * math.exp(-status.convergence_s / tau)
            # it starts from the code solution and leaves it for its own converging error
            error = w * dgps + (1.0 - w) * size * self._rtk_axes * self._wobble + carrier
            own = (1.0 - w) ** 2 * size * size * self._rtk_axes ** 2
            return error, self._sigma(w * w * dgps_var + own + carrier_var)
        white = FIXED_WHITE_M * self.rng.standard_normal(3)
        error = (white + FIXED_MULTIPATH_M * self._multipath) * self._rtk_axes + carrier
        if status.wrong_offset_enu_m is not None:
            error = error + np.asarray(status.wrong_offset_enu_m)
        own = (FIXED_WHITE_M ** 2 + FIXED_MULTIPATH_M ** 2) * self._rtk_axes ** 2
        return error, self._sigma(own + carrier_var)

    def _dgps(self, status: RtkStatus, single, common, selection, base_unit, c_rms, own_var) -> tuple:
        """The code-differential error and its mean square per axis."""
        own = single - common - selection
        decorrelation = DGPS_PPM * status.baseline_m
        base = DGPS_BASE_SIGMA_M * self._vertical * base_unit
        aged = common - self._common_then
        error = own + base + (decorrelation / c_rms[0]) * common + aged
        variance = (own_var + (DGPS_BASE_SIGMA_M ** 2 + decorrelation ** 2) * self._vertical ** 2
                    + self.errors.common_change_variance(status.diff_age_s))
        return error, variance

    def _sigma(self, variance: np.ndarray) -> tuple:
        """The reported sigmas: the type's RMS, scaled by this epoch's geometry."""
        return tuple((self.errors.dop * np.sqrt(variance)).tolist())


def _gauss_markov(z: np.ndarray, dt_s: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    if dt_s <= 0.0:
        return z
    a = math.exp(-dt_s / tau_s)
    return a * z + math.sqrt(1.0 - a * a) * rng.standard_normal(3)
