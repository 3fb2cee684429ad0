"""The car's speed as the steering envelope uses it: from trusted sources, or conservative.

Sources (the router's access control decides who may publish their keys):
- the estimator's state: its horizontal speed and variance; the speed the envelope uses
  while it is fresh;
- each GNSS receiver's velocity: a second, independent source that checks the first.

The speed used is the estimator's plus `speed_margin_sigmas` of its sigma, raised to a fresh
receiver's (plus its margin) when that is higher: an upper bound, since a faster car gets
the tighter envelope. When there is no fresh estimator speed (for `speed_timeout_s`), or a fresh
receiver disagrees with it beyond their sigmas (and what the car can accelerate in between
their stamps), the speed is `speed_conservative_mps` (the car's top speed by default), and the
reason is said: a car whose estimator died still steers gently, never wildly.

A sample is refused as a source, and counted by cause, when its speed or sigma is not a
finite number, is negative, is absurd (above `speed_absurd_mps`), or is stamped in the future
(beyond `speed_future_s`) or older than `speed_timeout_s` already. It is told the time (`now_s`,
monotonic; `wall_ns`, UTC for the stamps) and reads no clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from viena.common.display import number
from viena.common.settings import setting

ESTIMATOR, GNSS, CONSERVATIVE = "estimator", "gnss", "conservative"
#: causes a refused sample is counted under (a fixed set)
REFUSALS = ("non_finite", "negative", "absurd", "future", "stale", "not_valid")
#: how far from the moment a reading goes stale a remembered speed is still used
_EDGE_S = 1e-6


@dataclass(frozen=True)
class SpeedSettings:
    """Where the envelope's speed comes from (docs/steering.md#the-cars-speed)."""
    speed_timeout_s: float = setting(0.5, "no fresh estimator speed this long: use the conservative speed")
    speed_conservative_mps: float = setting(15.0, "the speed assumed when it is not known: the car's top speed "
                                            "(0 only for a drive on a bench, never on the road)")
    speed_margin_sigmas: float = setting(2.0, "the speed used is a source's speed plus this many of its sigmas")
    speed_agree_sigmas: float = setting(4.0, "a receiver's speed further than this many combined sigmas from "
                                       "the estimator's (plus speed_agree_floor_mps) is a disagreement")
    speed_agree_floor_mps: float = setting(0.5, "disagreements smaller than this are not counted")
    speed_max_accel_mps2: float = setting(4.0, "the car's largest acceleration: how far two stamps apart may differ")
    speed_absurd_mps: float = setting(70.0, "a speed above this is refused as a source")
    speed_future_s: float = setting(0.2, "a sample stamped further ahead of this host's clock is refused")


@dataclass(frozen=True)
class Speed:
    """The speed the envelope uses now, where it came from, and why not from the sources."""
    mps: float
    source: str                 # ESTIMATOR, "estimator+gnss0", ..., or CONSERVATIVE
    problem: str = ""           # why conservative ("" when the sources were used)


@dataclass
class _Reading:
    speed_mps: float
    sigma_mps: float
    t_ns: int
    received_s: float


@dataclass
class SpeedSources:
    settings: SpeedSettings = field(default_factory=SpeedSettings)

    def __post_init__(self):
        self._estimator: _Reading | None = None
        self._gnss: dict[str, _Reading] = {}
        self.refused: dict[str, int] = {}
        #: the last speed made from the sources, and the times (lo, hi] it holds for: the
        #: same readings give the same speed until one of them goes stale (`speed` is asked
        #: on every control tick, state and setpoint; the readings change less often)
        self._made: tuple[float, float, Speed] | None = None

    # -- samples ---------------------------------------------------------------------------
    def estimator(self, t_ns: int, speed_mps: float, sigma_mps: float, valid: bool,
                  now_s: float, wall_ns: int) -> str:
        """The estimator's state; the refusal cause, or "" if taken."""
        why = self._judge(t_ns, speed_mps, sigma_mps, valid, wall_ns)
        if not why:
            self._estimator = _Reading(speed_mps, sigma_mps, t_ns, now_s)
            self._made = None
        return why

    def gnss(self, unit: str, t_ns: int, speed_mps: float, sigma_mps: float, valid: bool,
             now_s: float, wall_ns: int) -> str:
        """A receiver's velocity; the refusal cause, or "" if taken."""
        why = self._judge(t_ns, speed_mps, sigma_mps, valid, wall_ns)
        if not why:
            self._gnss[unit] = _Reading(speed_mps, sigma_mps, t_ns, now_s)
            self._made = None
        return why

    def _judge(self, t_ns, speed, sigma, valid, wall_ns) -> str:
        s = self.settings
        why = ""
        if not valid:
            why = "not_valid"
        elif number(speed) is None or number(sigma) is None or not isinstance(t_ns, int):
            why = "non_finite"
        elif speed < 0 or sigma < 0:
            why = "negative"
        elif speed > s.speed_absurd_mps:
            why = "absurd"
        elif t_ns > wall_ns + s.speed_future_s * 1e9:
            why = "future"
        elif t_ns < wall_ns - s.speed_timeout_s * 1e9:
            why = "stale"
        if why:
            self.refused[why] = self.refused.get(why, 0) + 1
        return why

    # -- the speed used --------------------------------------------------------------------
    def speed(self, now_s: float) -> Speed:
        made = self._made
        if made is not None and made[0] < now_s <= made[1]:
            return made[2]
        s = self.settings
        est = self._estimator
        if est is None or now_s - est.received_s > s.speed_timeout_s:
            why = "no speed from the estimator yet" if est is None else \
                f"no fresh speed from the estimator for {now_s - est.received_s:.2f} s"
            return Speed(s.speed_conservative_mps, CONSERVATIVE, why)
        # which readings are fresh changes only when one goes stale: the speed holds until
        # then (kept clear of those moments by _EDGE_S, where float rounding could decide)
        lo, hi = -math.inf, est.received_s + s.speed_timeout_s
        for fix in self._gnss.values():
            stale_from = fix.received_s + s.speed_timeout_s
            if now_s - fix.received_s > s.speed_timeout_s:
                lo = max(lo, stale_from)
            else:
                hi = min(hi, stale_from)
        speed = self._from_sources(now_s, est)
        self._made = (lo + _EDGE_S, hi - _EDGE_S, speed)
        return speed

    def _from_sources(self, now_s: float, est: _Reading) -> Speed:
        """The speed from a fresh estimator reading and the fresh receivers that agree with it."""
        s = self.settings
        used = est.speed_mps + s.speed_margin_sigmas * est.sigma_mps
        agreeing = []
        for unit, fix in sorted(self._gnss.items()):
            if now_s - fix.received_s > s.speed_timeout_s:
                continue
            apart_s = abs(fix.t_ns - est.t_ns) * 1e-9
            allowed = s.speed_agree_sigmas * math.hypot(est.sigma_mps, fix.sigma_mps) + s.speed_agree_floor_mps \
                + s.speed_max_accel_mps2 * apart_s
            if abs(fix.speed_mps - est.speed_mps) > allowed:
                return Speed(s.speed_conservative_mps, CONSERVATIVE,
                             f"the estimator's {est.speed_mps:.1f} m/s and {unit}'s {fix.speed_mps:.1f} m/s "
                             f"disagree (by more than {allowed:.1f} m/s)")
            agreeing.append(unit)
            used = max(used, fix.speed_mps + s.speed_margin_sigmas * fix.sigma_mps)
        return Speed(used, "+".join([ESTIMATOR, *agreeing]))

