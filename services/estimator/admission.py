"""Which receivers' fixes the estimator may use: quality checks held for a while.

A receiver that has just found its fix, or has just come out of an underpass, reports
positions that jump by metres while its solution settles, often with sigmas that do not
say so. PX4's EKF2 uses a GPS only after its fixes have passed a set of checks for 10 s
without a break (EstimatorGpsStatus: fix type, satellites, PDOP, horizontal and vertical
accuracy, speed accuracy, and, while the vehicle stands, the position's drift and the
reported speed), and takes it out of use again while they fail. The same here, per
receiver, with the checks a viena fix can carry:

| check | setting | fails when |
|---|---|---|
| solution | | not valid / not SOL_COMPUTED (counted as `gnss_rejected.status`, before this) |
| satellites | `admit_min_sats` | fewer in the solution, when the fix says how many |
| horizontal sigma | `admit_max_sigma_h_m` | the larger horizontal sigma is above it |
| vertical sigma | `admit_max_sigma_v_m` | the vertical sigma is above it |
| speed sigma | `admit_max_speed_sigma_mps` | the velocity's horizontal sigma is above it |
| drift | `admit_max_drift_mps` | the car stands (the IMU says) and the fixes move |
| kind flicker | | the car stands and the kind changed more than KIND_FLICKER_CHANGES times in KIND_FLICKER_S |

The drift: the fixes' smoothed position moving faster than the setting over 3 s, or their
reported speed, smoothed, above it. A change of the solution's kind (corrections coming or
going) re-bases the positions it compares (the step it makes is not a drift) but keeps its
last verdict until a new 3 s span gives one. A kind that changes faster than that would
never be judged: hence the flicker check.

A receiver is on probation until its fixes have passed for `admit_hold_s` (counted on the
fixes' own clock); fixes on probation are counted in `gnss_rejected.probation`, and the
check that failed last in `gnss_rejected.quality_<check>`. A receiver in use that fails a
check has that fix refused; failing for `admit_hold_s` puts it back on probation. Each
receiver's standing is in the state (`gnss_admission`).
"""
from __future__ import annotations

import math
from collections import deque

from viena.services.estimator.settings import EstimatorSettings

#: the drift: the fixes' position, smoothed over about DRIFT_TAU_S, moved over DRIFT_SPAN_S
#: (a rate from one fix to the next is the fixes' noise over 50 ms, metres a second)
DRIFT_TAU_S = 1.0
DRIFT_SPAN_S = 3.0
#: more kind changes than this within KIND_FLICKER_S while the car stands: the receiver
#: flickers (its drift can never be judged). Converging from single point takes three
#: (single -> dgps -> float -> fixed), often within seconds; a fourth within 9 s is no
#: convergence, and a kind changing every 3 s or faster (which no 3 s drift span survives)
#: makes four in 9 s
KIND_FLICKER_CHANGES = 3
KIND_FLICKER_S = DRIFT_SPAN_S * 3


class _Receiver:
    __slots__ = ("passing_since", "failing_since", "admitted", "smooth", "anchor", "speed", "rate", "why", "kind",
                 "kind_changes")

    def __init__(self) -> None:
        self.passing_since: int | None = None
        self.failing_since: int | None = None
        self.admitted = False
        self.smooth: tuple | None = None        # (t, e, n): the position smoothed while standing
        self.anchor: tuple | None = None        # ... as it was DRIFT_SPAN_S ago
        self.speed = 0.0                        # the reported speed, smoothed while standing
        self.rate = 0.0                         # the smoothed position's last rate, m/s
        self.why = "no fix yet"
        self.kind: str | None = None            # the solution kind of its last fix
        self.kind_changes: deque[int] = deque()  # when it changed, within KIND_FLICKER_S

    def drift(self, t: int, e: float, n: float, speed: float | None, standing: bool) -> float:
        """How fast the fixes move while the car stands (m/s); 0 while it moves."""
        if not standing:
            self.smooth = self.anchor = None
            self.speed = self.rate = 0.0
            return 0.0
        if self.smooth is None or not 0 < t - self.smooth[0] < 2_000_000_000:
            # (a new start: the positions only; the last verdict on their rate stands)
            self.smooth = self.anchor = (t, e, n)
            self.speed = speed or 0.0
            return max(self.rate, self.speed)
        k = min(1.0, (t - self.smooth[0]) * 1e-9 / DRIFT_TAU_S)
        self.smooth = (t, self.smooth[1] + k * (e - self.smooth[1]), self.smooth[2] + k * (n - self.smooth[2]))
        if speed is not None:
            self.speed += k * (speed - self.speed)
        assert self.anchor is not None, "the anchor is set whenever the smoothed position is"
        span = (t - self.anchor[0]) * 1e-9
        if span >= DRIFT_SPAN_S:
            self.rate = math.hypot(self.smooth[1] - self.anchor[1], self.smooth[2] - self.anchor[2]) / span
            self.anchor = self.smooth
        return max(self.rate, self.speed)


class Admission:
    def __init__(self, settings: EstimatorSettings) -> None:
        s = settings
        self.hold_ns = int(s.admit_hold_s * 1e9)
        self.min_sats = s.admit_min_sats
        self.max_h, self.max_v = s.admit_max_sigma_h_m, s.admit_max_sigma_v_m
        self.max_speed_sigma = s.admit_max_speed_sigma_mps
        self.max_drift = s.admit_max_drift_mps
        self.receivers: dict[str, _Receiver] = {}

    def check(self, fix, enu_sigma, enu, standing: bool) -> str | None:
        """The first check `fix` fails, or None. `enu_sigma` its ENU sigmas, `enu` its
        position (for the drift), `standing` whether the IMU says the car stands."""
        r = self.receivers.setdefault(fix.unit, _Receiver())
        if fix.kind != r.kind:
            # corrections came or went: the fixes step, which is no drift (the verdict stays)
            if r.kind is not None:
                r.kind_changes.append(fix.t)
            r.kind, r.smooth, r.anchor = fix.kind, None, None
        while r.kind_changes and not 0 <= fix.t - r.kind_changes[0] <= KIND_FLICKER_S * 1e9:
            r.kind_changes.popleft()
        speed = None
        if fix.has_velocity:
            v = fix.vel_ecef_mps
            speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        drift = r.drift(fix.t, enu[0], enu[1], speed, standing)
        if fix.sats_used is not None and fix.sats_used < self.min_sats:
            return "sats"
        if max(enu_sigma[0], enu_sigma[1]) > self.max_h:
            return "sigma_h"
        if enu_sigma[2] > self.max_v:
            return "sigma_v"
        if fix.vel_sigma_mps is not None and fix.has_velocity and \
                math.hypot(fix.vel_sigma_mps[0], fix.vel_sigma_mps[1]) > self.max_speed_sigma:
            return "speed_sigma"
        if drift > self.max_drift:
            return "drift"
        if standing and len(r.kind_changes) > KIND_FLICKER_CHANGES:
            return "kind_flicker"
        return None

    def admit(self, fix, enu_sigma, enu, standing: bool) -> str | None:
        """None if `fix` may be used; else why not (`probation` or `quality_<check>`)."""
        r = self.receivers.setdefault(fix.unit, _Receiver())
        failed = self.check(fix, enu_sigma, enu, standing)
        if failed is None:
            r.failing_since = None
            if r.passing_since is None:
                r.passing_since = fix.t
            if not r.admitted and fix.t - r.passing_since >= self.hold_ns:
                r.admitted = True
            r.why = "in use" if r.admitted else "probation"
            return None if r.admitted else "probation"
        r.passing_since = None
        r.why = f"failing {failed}"
        if r.admitted:
            if r.failing_since is None:
                r.failing_since = fix.t
            elif fix.t - r.failing_since >= self.hold_ns:
                r.admitted = False
        return f"quality_{failed}"

    def report(self) -> dict[str, str]:
        """Each receiver's standing: `in use`, `probation`, or `failing <check>`."""
        return {u: r.why for u, r in sorted(self.receivers.items())}
