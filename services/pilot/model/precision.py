"""The precision rule: whether the GNSS solution under the estimate is good enough to follow
a route by (issue 28).

A route followed to decimetres needs corrections: on single-point fixes the estimate is a
metre off, an error every receiver on the car shares and the pilot follows faithfully
(docs/pilot.md#accuracy). The estimator says what its estimate rests on (its state's
`gnss_kind`, the best solution kind among the receivers it used lately, and
`gnss_diff_age_s`, the age of that solution's corrections); the pilot reads it there, not in
the fixes: its input is the estimate. The rule (`PrecisionSettings`): a kind at least
`min_solution`, with corrections at most `max_diff_age_s` old when that kind needs any;
when it is not met, `on_imprecise` says whether the pilot stops (refuses to start, and
stops following as for its other reasons) or warns (keeps following, and says so in
`pilot/state` for the person driving).

A verdict changes only once the new one has held for `precision_hold_s`, either way, so a
solution flickering between float and fixed (or one stray single-point fix) neither stops
a drive nor lets one start; until the first verdict has held, the rule is not met.
"""
from __future__ import annotations

from dataclasses import dataclass

from viena.common.samples.fix import SOLUTION_KINDS, solution_rank
from viena.common.settings import setting
from viena.services.pilot.model.estimate import Estimate

#: what the pilot does when the rule is not met
ACTIONS = ("stop", "warn")


@dataclass(frozen=True)
class PrecisionSettings:
    """Which GNSS solution the pilot follows with."""
    min_solution: str = setting("none", "the least GNSS solution under the estimate the pilot follows with, "
                                        "coarsest first; none: any (no rule)", choices=SOLUTION_KINDS)
    max_diff_age_s: float = setting(5.0, "... and its corrections at most this old (s), when that kind has any "
                                         "(sbas and better); 0: any age")
    on_imprecise: str = setting("stop", "when the rule is not met: stop (refuse to start, stop following), or "
                                        "warn (keep following, say so in pilot/state)", choices=ACTIONS)
    precision_hold_s: float = setting(1.0, "a change of verdict counts once it has held this long (s): a "
                                           "flickering solution neither stops nor starts the pilot")


class Precision:
    """The rule's verdict over time: `ok`, and the `reason` when not; `kind` and `age_s`
    as last judged. `judge` it with each estimate; a plain object, no clock."""

    def __init__(self, settings: PrecisionSettings | None = None):
        s = self.settings = settings or PrecisionSettings()
        if solution_rank(s.min_solution) < 0:
            raise ValueError(f"min_solution {s.min_solution!r}: one of {', '.join(SOLUTION_KINDS)}")
        if s.on_imprecise not in ACTIONS:
            raise ValueError(f"on_imprecise {s.on_imprecise!r}: one of {', '.join(ACTIONS)}")
        if not (s.max_diff_age_s >= 0.0 and s.precision_hold_s >= 0.0):
            raise ValueError("max_diff_age_s and precision_hold_s are 0 or more (s)")
        self.needed = solution_rank(s.min_solution)
        self.hold_ns = int(s.precision_hold_s * 1e9)
        self.ok = self.needed == 0                 # no rule: always met
        self.reason: str | None = None if self.ok else "no estimate yet"
        self.kind: str | None = None
        self.age_s: float | None = None
        self._pending: tuple[bool, int] | None = None   # a new verdict, and since when

    @property
    def stops(self) -> bool:
        """The rule is not met and the pilot must stop for it."""
        return not self.ok and self.settings.on_imprecise == "stop"

    def problem(self, kind: str | None, age_s: float | None) -> str | None:
        """Why this solution is not good enough, or None (no hysteresis: `judge` adds it)."""
        s = self.settings
        needs = s.min_solution if s.min_solution == "fixed" else f"{s.min_solution} or better"
        if kind is None:
            return f"the estimate does not say its GNSS solution (an older estimator?), the pilot needs {needs}"
        if solution_rank(kind) < self.needed:
            what = "no GNSS solution" if kind == "none" else f"solution {kind}"
            return f"{what}, the pilot needs {needs}"
        single = solution_rank("single")
        if self.needed > single and s.max_diff_age_s > 0.0 and solution_rank(kind) > single:
            if age_s is None or not age_s >= 0.0:      # (a negative or NaN age is no age)
                return f"corrections of unknown age, limit {s.max_diff_age_s:g} s"
            if age_s > s.max_diff_age_s:
                return f"corrections {age_s:.1f} s old, limit {s.max_diff_age_s:g} s"
        return None

    def judge(self, est: Estimate | None, now_ns: int) -> bool:
        """The verdict on the newest estimate at now_ns (the pilot's clock); returns `ok`."""
        self.kind = None if est is None else est.gnss_kind
        self.age_s = None if est is None else est.gnss_diff_age_s
        if self.needed == 0:
            return True
        why = "no estimate yet" if est is None else self.problem(self.kind, self.age_s)
        verdict = why is None
        if verdict == self.ok:
            self._pending = None
            self.reason = why
            return self.ok
        if self._pending is None:
            self._pending = (verdict, now_ns)
        held_ns = now_ns - self._pending[1]
        if held_ns >= self.hold_ns:
            self.ok, self.reason, self._pending = verdict, why, None
        elif verdict:                   # good again, not for long enough yet
            self.reason = (f"solution {self.kind} for {held_ns * 1e-9:.1f} s, "
                           f"needs {self.settings.precision_hold_s:g} s")
        return self.ok

    def report(self) -> dict:
        """pilot/state's fields."""
        return {"precision_ok": self.ok, "precision_kind": self.kind, "precision_diff_age_s": self.age_s,
                "precision_reason": self.reason}
