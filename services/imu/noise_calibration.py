"""`viena calibrate imu noise`: the Allan figures of parked recordings (docs/sensors.md#imu-noise-figures).

Each recording must be parked (the car standing, its motor as you want it measured) and
long enough for a figure; several recordings of the same board (each its own run) are
pooled curve by curve (model/allan.py: pooled). The figures are those of the values as
recorded: a logger that rounds (the car's old one wrote 0.01 g) adds its rounding to N,
and the report says how much.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from viena.services.imu.model.allan import TERMS, allan_deviation, fit_terms, pooled
from viena.services.imu.model.calibration import STANDARD_GRAVITY
from viena.services.imu.model.fitting import FitError
from viena.services.imu.recordings import Recording

#: shorter than this, no figure at all (N needs an octave or two around 1 s, with clusters)
MIN_SECONDS = 10.0
#: parked: every 1 s mean stays this close to the recording's median
MAX_ACCEL_WANDER_G = 0.02
MAX_GYRO_WANDER_DPS = 0.3
#: a parked board's mean rate is its bias (removed at boot by the VIENA firmware, a few deg/s at most raw)
MAX_STEADY_RATE_DPS = 3.0
NOMINAL_RATE_HZ = 82.5

#: sensor -> (Recording field, unit in the file)
SENSORS = {"gyro": ("gyro_dps", "deg/s"), "accel": ("accel_g", "g")}
#: how each term is shown: (unit, factor from the file's unit)
DISPLAY = {
    "gyro": {"quantization": ("deg", 1.0), "random_walk": ("deg/sqrt(h)", 60.0),
             "bias_instability": ("deg/h", 3600.0), "rate_random_walk": ("deg/h/sqrt(h)", 3600.0 * 60.0)},
    "accel": {"quantization": ("m/s", STANDARD_GRAVITY), "random_walk": ("m/s/sqrt(h)", STANDARD_GRAVITY * 60.0),
              "bias_instability": ("mg", 1000.0), "rate_random_walk": ("mg/sqrt(h)", 1000.0 * 60.0)},
}
SYMBOL = {"quantization": "Q", "random_walk": "N", "bias_instability": "B", "rate_random_walk": "K"}
NAME = {"gyro": {"random_walk": "angle random walk"}, "accel": {"random_walk": "velocity random walk"}}


@dataclass(frozen=True)
class SensorNoise:
    """One triad's figures: per axis its Allan curve and terms, in the file's unit."""

    sensor: str
    curves: tuple            # AllanCurve x 3
    terms: tuple             # NoiseTerms x 3
    resolution: float | None  # the recording's step (its logger's rounding), None: finer than 1e-6
    means: tuple             # per recording, per axis: the mean (the gyro: what the boot average left)


@dataclass(frozen=True)
class NoiseFigures:
    recordings: tuple
    seconds: float
    rate_hz: float
    sensors: dict            # sensor -> SensorNoise


def _rate(rec: Recording) -> float:
    rate = rec.rate_hz
    return rate if math.isfinite(rate) and 5 < rate < 1000 else NOMINAL_RATE_HZ


def check_parked(rec: Recording) -> None:
    """FitError unless the car stood still throughout: every 1 s mean of the accelerometer
    and gyro within MAX_*_WANDER of the recording's median (vibration averages out in a
    second; driving, turning or someone getting in does not)."""
    rate = _rate(rec)
    seconds = len(rec) / rate
    if seconds < MIN_SECONDS:
        raise FitError(f"{rec.name}: {seconds:.1f} s is too short for any figure: the random walk N needs "
                       f"at least {MIN_SECONDS:.0f} s parked, the bias instability ten minutes or more")
    window = max(1, int(round(rate)))
    n = len(rec) // window
    for values, limit, what, unit in ((rec.accel_g, MAX_ACCEL_WANDER_G, "specific force", "g"),
                                      (rec.gyro_dps, MAX_GYRO_WANDER_DPS, "rate", "deg/s")):
        means = values[:n * window].reshape(n, window, 3).mean(axis=1)
        off = np.abs(means - np.median(means, axis=0)).max(axis=1)
        if off.max() > limit:
            k = int(np.argmax(off > limit))
            raise FitError(f"{rec.name}: not parked: in the second from {k * window / rate:.1f} s the {what} moved "
                           f"{off[k]:.3g} {unit} from its median (more than {limit:g} {unit}): noise figures "
                           "need the car standing still throughout")
    g = float(np.linalg.norm(np.median(rec.accel_g, axis=0)))
    if not 0.8 < g < 1.2:
        raise FitError(f"{rec.name}: the specific force is {g:.2f} g, not about 1 g: not a resting board")
    rate_dps = float(np.linalg.norm(np.median(rec.gyro_dps, axis=0)))
    if rate_dps > MAX_STEADY_RATE_DPS:
        raise FitError(f"{rec.name}: not parked: turning steadily at {rate_dps:.2f} deg/s (a parked board's "
                       f"rate is its bias: within {MAX_STEADY_RATE_DPS:g} deg/s)")


def recording_resolution(values: np.ndarray) -> float | None:
    """The step the values were written in (0.01 for two decimals), if coarser than 1e-6."""
    v = np.asarray(values, float).ravel()
    for decimals in range(7):
        scaled = v * 10.0 ** decimals
        if np.all(np.abs(scaled - np.round(scaled)) < 1e-6):
            return 10.0 ** -decimals
    return None


def measure_noise(recordings: list[Recording]) -> NoiseFigures:
    """The figures of parked recordings of one board (FitError if one is not parked or too short)."""
    if not recordings:
        raise FitError("no recording given")
    for rec in recordings:
        check_parked(rec)
    sensors = {}
    for sensor, (attr, _) in SENSORS.items():
        curves, terms = [], []
        for axis in range(3):
            curve = pooled([allan_deviation(getattr(r, attr)[:, axis], _rate(r)) for r in recordings])
            curves.append(curve)
            terms.append(fit_terms(curve))
        values = np.concatenate([getattr(r, attr) for r in recordings])
        means = tuple(tuple(float(m) for m in getattr(r, attr).mean(axis=0)) for r in recordings)
        sensors[sensor] = SensorNoise(sensor, tuple(curves), tuple(terms), recording_resolution(values), means)
    if not any(getattr(t, term) is not None for s in sensors.values() for t in s.terms for term in TERMS):
        raise FitError("no noise figure could be read from the recordings")
    seconds = sum(len(r) / _rate(r) for r in recordings)
    rate = sum(len(r) for r in recordings) / seconds
    return NoiseFigures(tuple(r.name for r in recordings), seconds, rate, sensors)


# -- the calibration file's noise table -----------------------------------------------------------
def _sig(x: float | None) -> float:
    return float("nan") if x is None else float(f"{x:.4g}")


def noise_table(fig: NoiseFigures) -> dict:
    """The unit's `noise` table (docs/sensors.md#imu-noise-figures): per sensor, per axis,
    in the firmware's units (deg/s, g); nan where the recordings do not show a term."""
    table: dict = {"recordings": list(fig.recordings), "seconds": round(float(fig.seconds), 1),
                   "rate_hz": round(float(fig.rate_hz), 2)}
    for sensor, s in fig.sensors.items():
        sub: dict = {"unit": SENSORS[sensor][1]}
        for term in TERMS:
            sub[term] = [_sig(getattr(t, term)) for t in s.terms]
        sub["bias_instability_at_most"] = [_sig(t.bias_instability_at_most) for t in s.terms]
        if s.resolution is not None:
            sub["resolution"] = s.resolution
        if sensor == "gyro":
            sub["bias_after_boot_rms"] = [_sig(float(np.sqrt(np.mean(np.square(col)))))
                                          for col in zip(*s.means)]
        table[sensor] = sub
    return table


# -- the report --------------------------------------------------------------------------------------
def _shown(sensor: str, term: str, value: float | None, bound: float | None = None) -> str:
    factor = DISPLAY[sensor][term][1]
    if value is not None:
        return f"{value * factor:.3g}"
    if bound is not None:
        return f"<= {bound * factor:.3g}"
    return "-"


def report(fig: NoiseFigures) -> list[str]:
    """The figures as a table with units, then why a figure is missing."""
    lines = [f"noise of {' + '.join(fig.recordings)}: {fig.seconds:.1f} s parked at {fig.rate_hz:.1f} Hz",
             f"{'':24}{'x':>12}{'y':>12}{'z':>12}"]
    notes: dict[str, str] = {}
    for sensor, s in fig.sensors.items():
        lines.append(sensor)
        for term in ("random_walk", "bias_instability", "rate_random_walk", "quantization"):
            unit = DISPLAY[sensor][term][0]
            cells = [_shown(sensor, term, getattr(t, term),
                            t.bias_instability_at_most if term == "bias_instability" else None) for t in s.terms]
            name = NAME[sensor].get(term, term.replace("_", " "))
            lines.append(f"  {SYMBOL[term]} [{unit}]".ljust(24) + "".join(f"{c:>12}" for c in cells) + f"   {name}")
            for axis, t in zip("xyz", s.terms):
                if term in t.why_not:
                    notes.setdefault(f"{sensor} {SYMBOL[term]}", f"{t.why_not[term]} ({axis}...)")
        if s.resolution is not None:
            rounding = s.resolution / math.sqrt(12.0 * fig.rate_hz)       # white, of the steps' variance
            lines.append(f"  values recorded in steps of {s.resolution:g} {SENSORS[sensor][1]}: that rounding alone "
                         f"is an N of {_shown(sensor, 'random_walk', rounding)} {DISPLAY[sensor]['random_walk'][0]} "
                         "(adding in squares)")
        if sensor == "gyro":
            means = ", ".join("[" + ", ".join(f"{m:+.4f}" for m in row) + "]" for row in s.means)
            lines.append(f"  mean rate of each recording [deg/s] (what the boot average left): {means}")
    for key, why in notes.items():
        lines.append(f"{key} not given: {why.rsplit(' (', 1)[0]}")
    return lines


# -- the plot ----------------------------------------------------------------------------------------
def write_plot(fig: NoiseFigures, path: Path) -> Path:
    """The Allan deviation of each axis with its confidence, the fitted terms (dashed) and the
    bound on a floor not reached (dotted), as a PNG;
    a CSV of tau and deviation beside it if matplotlib is missing (returned: what was written)."""
    path = Path(path)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        out = path.with_suffix(".csv")
        _write_csv(fig, out)
        print(f"matplotlib is not installed: the curves went to {out} instead of a plot")
        return out
    figure, axes = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    for ax, (sensor, s) in zip(axes, fig.sensors.items()):
        unit, factor = DISPLAY[sensor]["bias_instability"]
        for axis, colour, curve, terms in zip("xyz", ("tab:red", "tab:green", "tab:blue"), s.curves, s.terms):
            y = curve.adev * factor
            ax.errorbar(curve.tau_s, y, yerr=[y - curve.lower * factor, curve.upper * factor - y],
                        fmt="o-", color=colour, ms=3, capsize=2, label=f"{axis}")
            grid = np.geomspace(curve.tau_s[0], curve.tau_s[-1], 100)
            ax.plot(grid, terms.model_adev(grid) * factor, "--", color=colour, lw=1,
                    label=f"{axis} fit: N {_shown(sensor, 'random_walk', terms.random_walk)} "
                          f"{DISPLAY[sensor]['random_walk'][0]}")
            if terms.bias_instability_at_most is not None:       # the floor can be no higher than this
                ax.hlines(0.664 * terms.bias_instability_at_most * factor, grid[len(grid) // 2], grid[-1],
                          colors=colour, linestyles=":", lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("tau [s]")
        ax.set_ylabel(f"Allan deviation [{unit}]")
        ax.set_title(f"{sensor} ({', '.join(fig.recordings)})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def _write_csv(fig: NoiseFigures, out: Path) -> None:
    rows = ["sensor,axis,tau_s,adev,lower,upper,clusters"]
    for sensor, s in fig.sensors.items():
        for axis, c in zip("xyz", s.curves):
            rows += [f"{sensor},{axis},{t:.6g},{a:.6g},{lo:.6g},{hi:.6g},{k}"
                     for t, a, lo, hi, k in zip(c.tau_s, c.adev, c.lower, c.upper, c.clusters)]
    out.write_text("\n".join(rows) + "\n")

