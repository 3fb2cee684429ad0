"""Draws docs/img/steering_envelope.png: the widest wheel angle and the fastest rate the
steering envelope allows at each speed (services/steering/model/lateral.py, its defaults).

    python -m benchmarks.steering_envelope_plot
"""
from __future__ import annotations

import matplotlib
import numpy as np

from viena.services.steering.model.lateral import LateralSettings, limits

RANGE_DEG, SLEW_DEG_S = 28.0, 30.0      # the car's range less the margin; the standing slew


def main(out: str = "docs/img/steering_envelope.png") -> None:
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = LateralSettings()
    speeds = np.linspace(0.5, 16, 300)
    fig, ax = plt.subplots(figsize=(7, 4))
    for engaging, label, style in ((False, "armed", "-"), (True, "first 1 s after an arm (engaging)", "--")):
        widest = [min(RANGE_DEG, limits(v, s, SLEW_DEG_S, engaging).max_wheel_deg) for v in speeds]
        ax.plot(speeds, widest, style, label=f"widest wheel angle, {label}")
    rates = [min(SLEW_DEG_S, limits(v, s, SLEW_DEG_S).rate_deg_s(0.0)) for v in speeds]
    ax.plot(speeds, rates, ":", label="fastest rate (deg/s): slew or lateral jerk")
    ax.axhline(RANGE_DEG, color="grey", lw=0.5)
    ax.text(0.6, RANGE_DEG + 0.4, "range (±28°)", fontsize=8)
    ax.set_xlabel("speed (m/s)")
    ax.set_ylabel("deg, deg/s")
    ax.set_ylim(0, 32)
    ax.set_title("The steering envelope by speed (defaults)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
