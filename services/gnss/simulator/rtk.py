"""Which solution a NovAtel OEM4 rover computes from the corrections it has read: the
position type and differential age of each epoch, on the receiver's own GPS clock, with
no bytes and no errors in it (differential.py sizes the errors; the twin feeds it).

What the manuals say, and what this machine does with it (vol. 1 = the OEM4 Installation
and Operation manual rev. 19, vol. 2 = the 2.310 Command and Log Reference rev. 18):

- Corrections are usable once the base's position (RTCM 1005/1006) and its observables
  (1001-1004) are in: the first usable epoch gives a pseudorange differential solution
  (PSRDIFF) at once (vol. 1 §6.5.1.4, "the pseudorange filter produces an immediate
  differential position while the RTK filter takes several additional seconds").
- The RTK filter's float solution comes after three base observations (vol. 1 §6.5.1.4:
  "available after three base observations are received"): NARROW_FLOAT for RT-2 with L1
  and L2 observables (1003/1004), L1_FLOAT for RT-20 or L1-only observables (1001/1002:
  vol. 1 Table 13, "L1 only ... 20 cm CEP (RT-20)").
- RT-2 fixes the ambiguities (NARROW_INT) after a convergence time that grows with the
  baseline (vol. 1 §6.5.1.3, "good results are available after a minute or so for short
  baselines, the time required increases with baseline length"): drawn per attempt
  (log-normal, seeded) around `fix_mean_s + fix_s_per_km * km`. Beyond `rt2_fix_max_km`
  (RT-2's tables stop at 35 km: vol. 1 Tables 14, 15) it floats for good. RT-20 "will always
  use floating L1 ambiguities" (vol. 1 §6.5.1): L1_FLOAT, never an integer type.
- Now and then a fix is wrong (`wrong_fix_*`): the type says NARROW_INT while the position
  is decimetres off, until the receiver notices and starts again from float.
- Losing the satellites (the sky's INSUFFICIENT_OBS) loses the ambiguities: float after
  it, fixed again sooner (`refix_factor`: the float solution still knows where it is).
- Corrections stop: the low-latency RTK solution goes on from the extrapolated base
  observations (vol. 1 §6.3.2), the ambiguities kept for `ambiguity_gap_s` = 30 s (vol. 1
  §6.5.1.4: "If the loss of differential corrections lasts longer than 30 seconds, the RTK
  filter is reset"), then float until the RTK timeout, 60 s "fixed ... and cannot be
  changed" (vol. 2 §2.6.16 DGPSTIMEOUT; §3.4.3 BESTPOS: the low-latency solution "for up
  to 60 seconds after reception of the last base station observations"); then PSRDIFF until
  DGPSTIMEOUT (factory 300 s, vol. 2 §2.5 and §2.6.16; vol. 1 §6.5.1.4: "an additional 240
  seconds by default"); then SINGLE, and the differential age is 0 again ("A differential
  age of 0 indicates that no differential correction was used", §3.4.3).
- PSRDIFFSOURCE / RTKSOURCE choose the base (vol. 2 §2.6.40, §2.6.47, Table 31), and a new
  PSRDIFFSOURCE drops the current corrections at once (§2.6.40 note 1).
- The differential age of an epoch is the time since the base's observation epoch it uses
  (vol. 2 §3.4.3 and §3.4.6: "Differential age in seconds").

A model that is not RTK-capable (a DGPS-only one) never goes past PSRDIFF.
"""
from __future__ import annotations

import math
import zlib
from collections import deque
from dataclasses import dataclass

import numpy as np

from viena.services.gnss.driver.novatel.enums import DgpsType, PositionType

#: What a receiver's model can compute from corrections (vol. 1 §1.1.1 lists the models).
RT2, RT20, DGPS = "RT-2", "RT-20", "DGPS"
#: Phases of the solution, coarsest first; "none" while the receiver has no fix at all.
PHASES = ("none", "single", "dgps", "float", "fixed")

RTK_TIMEOUT_S = 60.0                # vol. 2 §2.6.16: "RTK differential data is fixed at 60 seconds"
FACTORY_DGPS_TIMEOUT_S = 300.0      # vol. 2 §2.5 factory defaults: DGPSTIMEOUT 300
#: After an outage the float solution keeps up to this much of its convergence.
WARM_CREDIT_S = 60.0


def engine_of_model(model: str) -> str:
    """What an OEM4 model computes, from its name as VERSION gives it (vol. 2 §3.4.94: e.g.
    "RT2WA", "RT2WLBA"): RT2... is RT-2 (L1/L2), RT20... RT-20 (L1); any other model takes
    pseudorange corrections only (vol. 1 Table 13: "Any differential enabled OEM4")."""
    name = model.upper()
    if name.startswith("RT20"):
        return RT20
    if name.startswith("RT2"):
        return RT2
    return DGPS


@dataclass(frozen=True)
class RtkFigures:
    """The machine's numbers. The manuals give the shape (module docstring); the sizes are
    this twin's choice within it."""

    float_after_obs: int = 3            # base observations before the RTK filter's float solution
    fix_mean_s: float = 20.0            # mean time from float to fixed at 0 km ...
    fix_s_per_km: float = 9.0           # ... and per km of baseline (29 s at 1 km, 200 s at 20 km)
    fix_spread: float = 0.5             # sigma of the log of each attempt's time
    refix_factor: float = 0.3           # after an outage or a wrong fix: this share of the mean
    rt2_fix_max_km: float = 40.0        # RT-2 floats for good beyond this baseline
    fresh_s: float = 5.0                # ambiguities are resolved only on corrections this fresh
    ambiguity_gap_s: float = 30.0       # vol. 1 §6.5.1.4: a longer loss resets the RTK filter
    wrong_fix_chance: float = 0.01      # chance that a fix is wrong, at 0 km ...
    wrong_fix_chance_per_km: float = 0.001    # ... and per km of baseline
    wrong_fix_m: tuple = (0.2, 0.6)     # its horizontal offset (uniform) ...
    wrong_fix_s: tuple = (15.0, 60.0)   # ... and how long until the receiver notices (uniform)


DEFAULT_FIGURES = RtkFigures()


@dataclass(frozen=True)
class Source:
    """A PSRDIFFSOURCE or RTKSOURCE setting (vol. 2 Table 31): which bases' corrections count."""

    type: int = DgpsType.AUTO
    id: str = "ANY"

    def accepts(self, base_id: str) -> bool:
        """RTCM 3 corrections from `base_id`: AUTO takes the first received, RTCMV3 the
        given ID (or ANY); the other types are other formats (or none at all)."""
        if self.type == DgpsType.AUTO:
            return True
        if self.type == DgpsType.RTCMV3:
            return self.id.upper() == "ANY" or self.id.lstrip("0") == base_id.lstrip("0")
        return False


@dataclass(frozen=True)
class RtkStatus:
    """One epoch of the machine: what the receiver reports and what sizes its error."""

    phase: str                          # one of PHASES
    pos_type: PositionType | None       # None: the receiver's own (SINGLE, or WAAS with SBAS)
    diff_age_s: float = 0.0
    base_id: str = ""
    convergence_s: float = 0.0          # how long the float solution has converged
    baseline_m: float = 0.0
    l2: bool = False                    # dual-frequency RTK (RT-2 on 1003/1004)
    wrong_offset_enu_m: tuple | None = None   # a wrong fix's offset, while it lasts


SINGLE_STATUS = RtkStatus("single", None)
NONE_STATUS = RtkStatus("none", PositionType.NONE)


@dataclass
class _Observation:
    t_s: float              # when the receiver read it (its GPS time)
    epoch_s: float          # the base's observation epoch (GPS time)
    base_id: str
    l2: bool


class RtkMachine:
    """The rover's solution state, driven by events and asked epoch by epoch.

    ``observe`` and ``base_position`` queue what the receiver read, at its GPS time;
    ``at(t_s, outage=, baseline_m=)`` (non-decreasing t_s) applies the events up to t_s and
    says what epoch t_s reports. Deterministic for a seed and a sequence of calls.
    """

    # the RTK filter's state, set by _reset_filter
    _observations: int
    _float_since: float | None
    _credit_s: float
    _fix_at: float | None
    _fixed_since: float | None
    _wrong: tuple[tuple[float, float, float], float] | None    # (offset ENU m, when it is noticed)
    _warm: bool

    def __init__(self, engine: str = RT2, *, seed: int = 0, figures: RtkFigures = DEFAULT_FIGURES,
                 dgps_timeout_s: float = FACTORY_DGPS_TIMEOUT_S):
        self.engine = engine
        self.figures = figures
        self.dgps_timeout_s = dgps_timeout_s
        self.psr_source = Source()
        self.rtk_source = Source()
        self.rng = np.random.default_rng([seed, zlib.crc32(b"rtk")])
        self._events: deque = deque(maxlen=1000)
        self._bases: set[str] = set()           # bases whose position is known
        self._obs: _Observation | None = None   # the latest usable observation
        self._t = -math.inf
        self.fixes = 0
        self.wrong_fixes = 0
        self._reset_filter()

    # -- what the receiver read --------------------------------------------------------
    def observe(self, t_s: float, epoch_s: float, base_id: str, l2: bool) -> None:
        """A base's observables (1001-1004) read at `t_s` for its epoch `epoch_s`."""
        self._events.append((t_s, "obs", _Observation(t_s, epoch_s, str(base_id), l2)))

    def base_position(self, t_s: float, base_id: str) -> None:
        """A base's position (1005/1006) read at `t_s`."""
        self._events.append((t_s, "base", str(base_id)))

    def drop_corrections(self, t_s: float) -> None:
        """A new PSRDIFFSOURCE or RTKSOURCE: the corrections in use are dropped at once."""
        self._events.append((t_s, "drop", None))

    # -- the solution ------------------------------------------------------------------
    def at(self, t_s: float, *, outage: bool = False, baseline_m: float = 0.0) -> RtkStatus:
        """The solution of epoch `t_s` (GPS seconds): its phase, type, age and convergence."""
        while self._events and self._events[0][0] <= t_s:
            self._apply(*self._events.popleft())
        self._t = t_s
        if outage:
            self._lose_lock()
            return NONE_STATUS
        obs = self._obs
        if obs is None:
            return SINGLE_STATUS
        age = max(0.0, t_s - obs.epoch_s)
        if age > RTK_TIMEOUT_S:
            self._reset_filter()
        elif age > self.figures.ambiguity_gap_s and self._fixed_since is not None:
            self._unfix()
        rtk = (self.engine in (RT2, RT20) and age <= RTK_TIMEOUT_S and self.rtk_source.accepts(obs.base_id)
               and self._observations >= self.figures.float_after_obs)
        if rtk:
            return self._rtk(t_s, obs, age, baseline_m)
        if age <= self.dgps_timeout_s and self.psr_source.accepts(obs.base_id):
            return RtkStatus("dgps", PositionType.PSRDIFF, age, obs.base_id, baseline_m=baseline_m)
        if age > self.dgps_timeout_s:
            self._obs = None
        return SINGLE_STATUS

    def _rtk(self, t_s: float, obs: _Observation, age: float, baseline_m: float) -> RtkStatus:
        f, l2 = self.figures, obs.l2 and self.engine == RT2
        if self._float_since is None:
            self._float_since = t_s - self._credit_s         # warm: the convergence it kept
            self._credit_s = 0.0
        if self._wrong is not None and t_s >= self._wrong[1]:
            self._unfix()                                   # the receiver noticed
        can_fix = l2 and baseline_m <= f.rt2_fix_max_km * 1000.0
        if can_fix and self._fixed_since is None and age <= f.fresh_s:
            if self._fix_at is None:
                self._fix_at = t_s + self._time_to_fix(baseline_m, self._warm)
                self._warm = False
            elif t_s >= self._fix_at:
                self._fix(t_s, baseline_m)
        convergence = t_s - self._float_since
        if self._fixed_since is not None:
            wrong = None if self._wrong is None else self._wrong[0]
            return RtkStatus("fixed", PositionType.NARROW_INT, age, obs.base_id, convergence, baseline_m, True, wrong)
        kind = PositionType.NARROW_FLOAT if l2 else PositionType.L1_FLOAT
        return RtkStatus("float", kind, age, obs.base_id, convergence, baseline_m, l2)

    # -- transitions -------------------------------------------------------------------
    def _apply(self, t_s: float, kind: str, value) -> None:
        if kind == "base":
            self._bases.add(value)
        elif kind == "drop":
            self._obs = None
            self._reset_filter()
        elif value.base_id in self._bases and (self.psr_source.accepts(value.base_id)
                                               or self.rtk_source.accepts(value.base_id)):
            last = self._obs
            gap = math.inf if last is None else value.epoch_s - last.epoch_s
            if last is not None and (last.base_id != value.base_id or gap > RTK_TIMEOUT_S):
                self._reset_filter()                 # another base, or the old one timed out
            elif gap > self.figures.ambiguity_gap_s and self._fixed_since is not None:
                self._unfix()
            self._obs = value
            self._observations += 1

    def _reset_filter(self) -> None:
        """The RTK filter starts over: no base model, no float, no ambiguities."""
        self._observations = 0
        self._float_since = None
        self._credit_s = 0.0
        self._fix_at = None
        self._fixed_since = None
        self._wrong = None
        self._warm = False

    def _time_to_fix(self, baseline_m: float, warm: bool) -> float:
        """One attempt's time from float (or from a warm restart) to fixed."""
        f = self.figures
        mean = f.fix_mean_s + f.fix_s_per_km * baseline_m / 1000.0
        if warm:
            mean *= f.refix_factor
        draw = math.exp(f.fix_spread * float(self.rng.standard_normal()) - 0.5 * f.fix_spread ** 2)
        return max(1.0, mean * draw)

    def _fix(self, t_s: float, baseline_m: float) -> None:
        f = self.figures
        self._fixed_since = t_s
        self._fix_at = None
        self.fixes += 1
        chance = min(1.0, f.wrong_fix_chance + f.wrong_fix_chance_per_km * baseline_m / 1000.0)
        if self.rng.random() < chance:
            self.wrong_fixes += 1
            size = float(self.rng.uniform(*f.wrong_fix_m))
            heading = float(self.rng.uniform(0.0, 2.0 * math.pi))
            up = 0.5 * size * float(self.rng.standard_normal())
            offset = (size * math.sin(heading), size * math.cos(heading), up)
            self._wrong = (offset, t_s + float(self.rng.uniform(*f.wrong_fix_s)))

    def _unfix(self) -> None:
        """Back to float (a wrong fix noticed, or the ambiguities lost in a gap): the next
        attempt starts warm, on the next fresh corrections."""
        self._fixed_since = None
        self._wrong = None
        self._fix_at = None
        self._warm = True

    def _lose_lock(self) -> None:
        """Too few satellites: every ambiguity is lost; the float restarts warm, keeping up
        to WARM_CREDIT_S of its convergence (it still knows where it is)."""
        if self._float_since is not None:
            self._credit_s = min(WARM_CREDIT_S, self._t - self._float_since)
            self._float_since = None
            self._unfix()
