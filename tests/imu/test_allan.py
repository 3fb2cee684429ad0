"""The Allan deviation and the IEEE 952 terms read from it (services/imu/model/allan.py), on
synthetic series whose terms are known: white rate noise (N), flicker (B), a random walk
of the rate (K), angle quantisation (Q), a chip's low-pass."""
from __future__ import annotations

import math

import numpy as np
import pytest

from viena.services.imu.model.allan import AllanCurve, allan_deviation, fit_terms, pooled


def flicker_white_walk(n: int, rate_hz: float, n_rw: float, b: float, k: float, seed: int) -> np.ndarray:
    """White rate noise of random walk N, flicker of bias instability B (one-sided PSD
    B^2 / (pi f), IEEE 952's S(f) = B^2 / (2 pi f) two-sided) shaped in the frequency domain,
    and a random walk of the rate K."""
    rng = np.random.default_rng(seed)
    white = rng.standard_normal(n) * n_rw * math.sqrt(rate_hz)
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    gain = np.zeros_like(f)
    gain[1:] = np.sqrt(b * b / (math.pi * f[1:]) / (2.0 / rate_hz))   # white of unit variance: PSD 2 / rate
    flicker = np.fft.irfft(np.fft.rfft(rng.standard_normal(n)) * gain, n)
    walk = np.cumsum(rng.standard_normal(n)) * k / math.sqrt(rate_hz)
    return white + flicker + walk


def test_the_fit_recovers_n_b_and_k_of_a_known_series():
    """Four hours at 10 Hz, N = 0.005 deg/sqrt(s), B = 0.003 deg/s, K = 0.0002 deg/s/sqrt(s):
    the floor spans 6 to 300 s. N within 3 %, B within 10 %, K within 35 % (its part of the
    curve has the fewest clusters)."""
    n_rw, b, k = 0.005, 0.003, 0.0002
    curve = allan_deviation(flicker_white_walk(144_000, 10.0, n_rw, b, k, seed=1), 10.0)
    terms = fit_terms(curve)
    assert terms.random_walk == pytest.approx(n_rw, rel=0.03)
    assert terms.bias_instability == pytest.approx(b, rel=0.10)
    assert terms.rate_random_walk == pytest.approx(k, rel=0.35)
    assert terms.quantization is None and "quantization" in terms.why_not
    assert 10.0 < terms.floor_tau_s < 150.0
    floor = curve.adev[np.argmin(abs(curve.tau_s - terms.floor_tau_s))]
    assert terms.model_adev(terms.floor_tau_s)[0] == pytest.approx(floor, rel=0.15)


def test_white_noise_alone_gives_n_and_says_why_b_and_k_are_not_there():
    """A minute of white noise: N, and for B only the bound the curve sets, with the reason."""
    rate, sigma = 82.5, 0.03
    y = np.random.default_rng(2).standard_normal(4950) * sigma
    curve = allan_deviation(y, rate)
    assert curve.adev[0] == pytest.approx(sigma, rel=0.03)            # sigma(tau0) of white noise
    terms = fit_terms(curve)
    assert terms.random_walk == pytest.approx(sigma / math.sqrt(rate), rel=0.08)
    assert terms.bias_instability is None and terms.rate_random_walk is None
    assert "no flat floor" in terms.why_not["bias_instability"]
    assert "no slope +1/2" in terms.why_not["rate_random_walk"]
    lowest = curve.adev[curve.clusters >= 5].min()
    assert lowest / 0.664 < terms.bias_instability_at_most < 2.0 * lowest / 0.664


def test_angle_quantisation_is_q():
    """A rate-integrating sensor that reports its angle in whole steps S, dithered by white
    angle noise of one step: the angle error is white, Q^2 = sigma^2 + S^2 / 12 (IEEE 952 C.1.2),
    slope -1 up to where the angle random walk N takes over."""
    rate, step, n_rw = 100.0, 1e-3, 1e-3
    rng = np.random.default_rng(3)
    angle = np.cumsum(rng.standard_normal(200_000)) * n_rw / math.sqrt(rate) + rng.standard_normal(200_000) * step
    y = np.diff(np.round(angle / step)) * step * rate
    terms = fit_terms(allan_deviation(y, rate))
    assert terms.quantization == pytest.approx(math.sqrt(step ** 2 + step ** 2 / 12.0), rel=0.05)
    assert terms.random_walk == pytest.approx(n_rw, rel=0.1)


def test_a_chips_low_pass_is_left_out_of_the_fit():
    """White noise through a 10 Hz first-order low-pass at 82.5 Hz (the ITG-3200's): the
    shortest taus fall more slowly than white noise; N is still read off the -1/2 line."""
    rate, n_rw = 82.5, 0.005
    w = np.random.default_rng(4).standard_normal(40_000) * n_rw * math.sqrt(rate)
    alpha = 1.0 - math.exp(-2.0 * math.pi * 10.0 / rate)
    y = np.empty_like(w)
    low = 0.0
    for i, x in enumerate(w):
        low += alpha * (x - low)
        y[i] = low
    curve = allan_deviation(y, rate)
    assert curve.adev[0] < 0.7 * n_rw * math.sqrt(rate)              # the filter is there
    assert fit_terms(curve).random_walk == pytest.approx(n_rw, rel=0.06)


def test_recordings_of_one_board_pool_into_one_curve():
    """Two halves of a series, pooled, give the whole's curve where both reach."""
    y = np.random.default_rng(5).standard_normal(20_000)
    whole = allan_deviation(y, 50.0)
    a, b = allan_deviation(y[:10_000], 50.0), allan_deviation(y[10_000:], 50.0)
    both = pooled([a, b])
    k = len(a.tau_s)
    assert np.allclose(both.tau_s, whole.tau_s[:k])
    assert np.allclose(both.adev[:6], whole.adev[:6], rtol=0.05)
    assert list(both.clusters) == list(a.clusters + b.clusters)
    assert isinstance(both, AllanCurve) and np.all(both.lower < both.adev) and np.all(both.upper > both.adev)
