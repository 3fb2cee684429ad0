"""What the GNSS side keeps of the fixes' verdicts, as small pieces that decide, not act.

- `Disagreement`: how long usable fixes have kept failing the gate, and how many in a row
  the IMU-driven velocity was far off GNSS's (then gnss_update.py has GNSS believed);
- `SolutionSteps`: each receiver's solution kind, and whether a step to a better one is
  believed past the gate;
- `solution`: what the estimate rests on, from the last fix each receiver had taken;
- `floors`, `lever_arms`: the settings they read, checked.
"""
from __future__ import annotations

import math

from viena.common.samples.fix import SOLUTION_KINDS, solution_rank

#: the IMU-driven velocity this far (m/s) off GNSS's at this many fixes in a row: the IMU
#: is wrong (150 m/s^2 for a second is in the sensor's range, but no car's motion)
IMU_CONTRADICTED_MPS = 10.0
IMU_CONTRADICTED_FIXES = 2
#: a step to a better kind is believed past the gate at most this often per receiver (s):
#: a float <-> fixed flicker (or a wrong integer fix, again and again) gets no more
STEP_BELIEVED_EVERY_S = 10.0
#: ... and only when it is within this many of the old kind's sigmas (and the new fix's)
STEP_BELIEVED_SIGMAS = 3.0


class Disagreement:
    """GNSS against the filter: refusals in a row (since when) and IMU contradictions."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.since: int | None = None      # usable fixes failing the gate since
        self.last_t = 0                    # ... the last of them
        self.contradicted = 0              # fixes in a row whose velocity the IMU's left far

    def agreed(self) -> None:
        self.since = None

    def refused_for(self, t: int, timeout_ns: int) -> float:
        """A fix refused at t: how long (s) the refusals have lasted. Refusals before a
        spell without fixes (longer than `timeout_ns`) are not this disagreement: the time
        without fixes is no time GNSS disagreed."""
        if self.since is None or t - self.last_t > timeout_ns:
            self.since = t
            self.last_t = t
            return 0.0
        self.last_t = t
        return (t - self.since) * 1e-9

    def imu_contradicted(self, nu_v, vel_ok: bool) -> bool:
        """The filter's velocity, which the IMU drives, is more than IMU_CONTRADICTED_MPS off
        GNSS's horizontally at IMU_CONTRADICTED_FIXES fixes in a row."""
        if vel_ok or nu_v[0] * nu_v[0] + nu_v[1] * nu_v[1] < IMU_CONTRADICTED_MPS ** 2:
            self.contradicted = 0
            return False
        self.contradicted += 1
        return self.contradicted >= IMU_CONTRADICTED_FIXES


class SolutionSteps:
    """Each receiver's solution kind and the steps between kinds. A change of kind
    (corrections came, converged, stopped) is a known step; the first fix of a better kind
    is believed past the gate (its position widens to it), but only a step the old kind's
    fixes could have made, horizontally within STEP_BELIEVED_SIGMAS of their level and
    this fix's sigma, and once per receiver every STEP_BELIEVED_EVERY_S: a wrong integer
    fix is a step to a better kind too, and a flicker steps again and again."""

    def __init__(self) -> None:
        self.kind: dict[str, str] = {}          # each receiver's solution kind, last fix used
        self.believed_t: dict[str, int] = {}    # when each receiver's last step was believed
        self.restart()

    def restart(self) -> None:
        #: receivers whose next fix steps to a better kind: the old kind's level (variances E, N, U)
        self.stepped_up: dict[str, tuple | None] = {}

    def changed(self, unit: str, kind: str) -> str | None:
        """`unit`'s fix is of `kind`: the kind before, if this is a change (not its first)."""
        before = self.kind.get(unit)
        if before == kind:
            return None
        self.kind[unit] = kind
        return before

    def stepped(self, unit: str, before: str, kind: str, old_level: tuple | None) -> None:
        """`unit` stepped from `before` to `kind`, the old kind's variances `old_level`."""
        if solution_rank(kind) > solution_rank(before):
            self.stepped_up[unit] = old_level
        else:
            self.stepped_up.pop(unit, None)

    def believe(self, unit: str, nu_p, Rp, old_level: tuple, t: int) -> str | None:
        """Why a step to a better kind (innovation nu_p, covariance Rp, at t; the old kind's
        variances `old_level`) is not believed, or None: it is (and its time kept)."""
        step_h = math.hypot(nu_p[0], nu_p[1])
        var_h = max(old_level[0], old_level[1]) + max(float(Rp[0, 0]), float(Rp[1, 1]))
        if step_h > STEP_BELIEVED_SIGMAS * math.sqrt(var_h):
            return f"the step to a better solution ({step_h:.2f} m) is beyond the old one's {math.sqrt(var_h):.2f} m"
        last_t = self.believed_t.get(unit)
        if last_t is not None and 0 <= t - last_t < STEP_BELIEVED_EVERY_S * 1e9:
            return f"a step to a better solution {(t - last_t) * 1e-9:.1f} s after the last one believed"
        self.believed_t[unit] = t
        return None


def solution(solutions: dict[str, tuple[int, str, float | None]], t: int,
             timeout_ns: int) -> tuple[str, float | None, dict[str, str]]:
    """What the estimate rests on at time t, from each receiver's last fix the filter took
    (t, kind, diff_age_s): the best solution kind among those within `timeout_ns` ("none"
    if none), the age of that kind's corrections now (the youngest, when they carry one and
    the kind has any), and each such receiver's kind."""
    live = {u: v for u, v in solutions.items() if t - v[0] < timeout_ns}
    kinds = {u: v[1] for u, v in sorted(live.items())}
    if not live:
        return "none", None, kinds
    best = max(kinds.values(), key=solution_rank)
    ages = [age + max(0.0, (t - tf) * 1e-9) for tf, kind, age in live.values()
            if kind == best and age is not None]
    age = min(ages) if ages and solution_rank(best) > solution_rank("single") else None
    return best, age, kinds


def floors(given: dict) -> dict[str, tuple[float, float, float]]:
    """`gnss_sigma_floor_m` as sigmas along E, N, U per solution kind."""
    out = {}
    for kind, hv in given.items():
        if solution_rank(kind) < 0:
            raise ValueError(f"gnss_sigma_floor_m.{kind}: a solution kind, one of {', '.join(SOLUTION_KINDS)}")
        if len(hv) != 2 or min(hv) < 0.0:
            raise ValueError(f"gnss_sigma_floor_m.{kind}: [horizontal, vertical] in m, got {list(hv)!r}")
        out[kind] = (float(hv[0]), float(hv[0]), float(hv[1]))
    return out


def lever_arms(settings) -> tuple[tuple, dict[str, tuple]]:
    """The default lever arm and each receiver's, checked (and the velocities' latencies)."""
    default = tuple(float(v) for v in settings.default_lever_arm_m)
    levers = {u: tuple(float(v) for v in arm) for u, arm in settings.gnss_lever_arm_m.items()}
    for arm in (default, *levers.values()):
        if len(arm) != 3:
            raise ValueError("a lever arm is [x right, y forward, z up] in m")
    for unit, latency in settings.gnss_vel_latency_s.items():
        if not 0.0 <= latency <= 1.0:
            raise ValueError(f"gnss_vel_latency_s.{unit}: a latency of 0 to 1 s, got {latency!r}")
    return default, levers
