"""The steering axis under the EPOS position controller, as measured on the car.

A position loop with a derivative kick on setpoint steps, viscous damping and stick-slip
friction, integrated at the EPOS position controller's 1 kHz:

    e  = r(t - delay) - x
    u  = wn² e + kd de/dt                     (the controller's push, per unit inertia)
    a  = u - 2 zeta wn v - fc sign(v)         (while moving)
    the axis sticks when v would change sign and |u| <= fs, and breaks free when |u| > fs.

The constants come from `fit.py` (scipy) on the car's recordings (shared/data/steering):
`TRAJ01` from traj01.mat (gains P 50, I 1, D 3 with feed-forward: the tuned loop) is the
twin's default; `CHIRP005` from chirp005.mat (P 30, I 0, D 5: a loop far too soft to
overcome the tyres' friction, which moves in stick-slip jumps). See README.md for the fit
quality of each.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

DT_S = 0.001          # the EPOS position controller's sample time (1 kHz)


@dataclass(frozen=True)
class PlantParams:
    wn: float                  # rad/s, closed-loop natural frequency
    zeta: float                # damping ratio of the velocity feedback
    kd: float                  # derivative kick gain (s)
    fs: float                  # static friction, qc/s² per unit inertia
    fc: float                  # Coulomb friction while moving, qc/s²
    delay_s: float             # from setpoint to the position loop
    max_speed_qc_s: float = 150_000.0


#: fitted to traj01.mat (see fit.py; RMS error in README.md)
TRAJ01 = PlantParams(wn=13.69, zeta=0.463, kd=0.998, fs=687.0, fc=0.0, delay_s=0.0554)
#: fitted to chirp005.mat
CHIRP005 = PlantParams(wn=0.3256, zeta=0.9985, kd=0.9996, fs=447481.0, fc=2612.0, delay_s=0.0361)


class PositionPlant:
    """One axis: `step(setpoint, dt)` advances by whole controller samples."""

    def __init__(self, params: PlantParams = TRAJ01, position_qc: float = 0.0):
        self.params = params
        self.x = float(position_qc)
        self.v = 0.0
        n = max(1, round(params.delay_s / DT_S))
        self._pipe: deque[float] = deque([self.x] * n, maxlen=n)
        self._e_prev = 0.0
        self._carry = 0.0

    @property
    def demand(self) -> float:
        """The setpoint the loop acts on now (the oldest in the delay line)."""
        return self._pipe[0]

    def reset(self, position_qc: float) -> None:
        """Power stage on: the loop starts from where the axis is, at rest."""
        self.x = float(position_qc)
        self.v = 0.0
        self._pipe.extend([self.x] * len(self._pipe))        # (always full: maxlen items)
        self._e_prev = 0.0

    def step(self, setpoint_qc: float, dt: float) -> None:
        """Advance by dt seconds (rounded to whole 1 ms samples, the remainder carried)."""
        self._carry += dt
        n = int(self._carry / DT_S + 1e-9)
        self._carry -= n * DT_S
        if n <= 0:
            return
        p = self.params
        kp, kv = p.wn * p.wn, 2.0 * p.zeta * p.wn
        # 1000 samples a virtual second: the state in locals, written back once
        kd, fs, fc, vmax = p.kd, p.fs, p.fc, p.max_speed_qc_s
        pipe, r = self._pipe, float(setpoint_qc)
        x, v, e_prev = self.x, self.v, self._e_prev
        for _ in range(n):
            pipe.append(r)
            e = pipe[0] - x
            u = kp * e + kd * (e - e_prev) / DT_S
            e_prev = e
            if v == 0.0 and abs(u) <= fs:
                continue
            a = u - kv * v - fc * math.copysign(1.0, v if v != 0.0 else u)
            v_new = v + a * DT_S
            if v != 0.0 and (v_new > 0.0) != (v > 0.0) and abs(u) <= fs:
                v_new = 0.0
            v = max(-vmax, min(vmax, v_new))
            x += v * DT_S
        self.x, self.v, self._e_prev = x, v, e_prev

    def coast(self, dt: float) -> None:
        """Power stage off: the axis stays where friction holds it."""
        self._carry = 0.0
        self.v = 0.0
        self._e_prev = 0.0
