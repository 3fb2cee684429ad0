"""Steering calibration: from encoder counts to the bicycle model's wheel angle.

Two calibrations meet here (docs/steering.md#calibration):

- the static laser fit, done once on the car: delta[deg] = slope * (qc - zeroRef) with
  slope = -7.5014e-4 deg/qc, valid within +-29 deg (both are settings);
- the power-up sweep: the encoder has no index, so its counter starts at 0 wherever the
  wheel stands at power-up. With the power stage off, a person turns the wheel to both
  locks and back; min and max of the counter give zeroRef = round(min + (max - min) / 2).
  The result holds until the drive is power-cycled.

The old code started min and max at 0 and checked nothing, so a sweep that was never done
(shared/data/steering/encoder_logs: min 0, max 519) became a "calibration". Here a sweep
starts from the first sample, counts must move like a hand turns a wheel, and the span
must be near the car's ~95 000 qc lock to lock; anything else is refused with the reason.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from viena.common.settings import setting

SLOPE_DEG_PER_QC = -7.5014e-4
LIMIT_DEG = 29.0


class CalibrationRefused(ValueError):
    """A calibration that cannot be right; the message says why."""


@dataclass(frozen=True)
class CalibrationSettings:
    slope_deg_per_qc: float = setting(SLOPE_DEG_PER_QC, "wheel angle per encoder count (the laser fit)")
    limit_deg: float = setting(LIMIT_DEG, "the wheel's lock either side of the middle")
    #: the car's sweeps span 95 060 .. 95 352 qc; far outside means no sweep or a slipping gear
    min_span_qc: int = setting(90_000, "shortest lock-to-lock sweep accepted")
    max_span_qc: int = setting(100_000, "longest lock-to-lock sweep accepted")
    #: zeroRef must sit in the middle of the sweep (it is computed so; a typed one may not)
    zero_tolerance_qc: int = setting(2, "how far a given zero may be from the sweep's middle")
    #: a sweep is over when the wheel is back near the middle and still
    return_tolerance_qc: int = setting(6_000, "back this near the middle ends a sweep ...")
    sweep_settle_s: float = setting(0.5, "... once the wheel has been still this long")
    still_qc: int = setting(200, "moving less than this is still")
    #: counter jumps no hand can make between two readings: an encoder or bus glitch.
    #: A busy host reads less often, so the allowance grows with the time between readings
    #: at a speed no person turns a steering wheel (lock to lock, ~95 000 qc, in < 1 s).
    max_jump_qc: int = setting(20_000, "a counter jump larger than this between readings is a glitch ...")
    max_hand_speed_qc_s: float = setting(100_000.0, "... plus this much per second between them")


@dataclass(frozen=True)
class Calibration:
    """A checked calibration; build it with `check_calibration`."""
    min_qc: int
    max_qc: int
    zero_qc: int
    slope_deg_per_qc: float = SLOPE_DEG_PER_QC
    limit_deg: float = LIMIT_DEG

    @property
    def span_qc(self) -> int:
        return self.max_qc - self.min_qc

    def angle_deg(self, qc: float) -> float:
        """The laser fit, not limited (for telling how far out a wheel is)."""
        return self.slope_deg_per_qc * (qc - self.zero_qc)

    def measured_deg(self, qc: float) -> float:
        """The wheel angle the fit vouches for: limited to +-limit_deg."""
        return max(-self.limit_deg, min(self.limit_deg, self.angle_deg(qc)))

    def qc_of(self, angle_deg: float) -> float:
        return self.zero_qc + angle_deg / self.slope_deg_per_qc

    @property
    def range_deg(self) -> tuple[float, float]:
        """Angles both reachable (inside the locks) and vouched for (inside +-limit_deg)."""
        a, b = self.angle_deg(self.min_qc), self.angle_deg(self.max_qc)
        return max(-self.limit_deg, min(a, b)), min(self.limit_deg, max(a, b))

    def limits_qc(self) -> tuple[int, int]:
        """The calibrated range as counter values, for the drive's software limits 0x607D."""
        lo, hi = self.range_deg
        a, b = self.qc_of(lo), self.qc_of(hi)
        return math.ceil(min(a, b)), math.floor(max(a, b))

    def as_dict(self) -> dict:
        lo, hi = self.range_deg
        return {"min_qc": self.min_qc, "max_qc": self.max_qc, "zero_qc": self.zero_qc,
                "span_qc": self.span_qc, "slope_deg_per_qc": self.slope_deg_per_qc,
                "range_deg": [lo, hi]}


def zero_ref(min_qc: int, max_qc: int) -> int:
    """zeroRef as the car's code computed it: round((max - min) / 2 + min)."""
    return round((max_qc - min_qc) / 2 + min_qc)


def check_calibration(min_qc, max_qc, zero_qc=None,
                      settings: CalibrationSettings = CalibrationSettings()) -> Calibration:
    """A Calibration, or CalibrationRefused saying what is wrong with these numbers."""
    for name, v in (("min", min_qc), ("max", max_qc), ("zeroRef", zero_qc)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int)):
            raise CalibrationRefused(f"{name} must be an integer count, got {v!r}")
    if max_qc < min_qc:
        raise CalibrationRefused(f"max {max_qc} is below min {min_qc}")
    span = max_qc - min_qc
    if not settings.min_span_qc <= span <= settings.max_span_qc:
        hint = ("the wheel was not turned lock to lock" if span < settings.min_span_qc
                else "more than lock to lock: a slipping encoder gear or a glitch")
        raise CalibrationRefused(f"span {span} qc is outside {settings.min_span_qc}.."
                                 f"{settings.max_span_qc} qc ({hint})")
    middle = zero_ref(min_qc, max_qc)
    if zero_qc is None:
        zero_qc = middle
    elif abs(zero_qc - middle) > settings.zero_tolerance_qc:
        raise CalibrationRefused(f"zeroRef {zero_qc} is not the middle {middle} of {min_qc}..{max_qc}")
    if not math.isfinite(settings.slope_deg_per_qc) or settings.slope_deg_per_qc == 0:
        raise CalibrationRefused(f"slope {settings.slope_deg_per_qc} deg/qc is not usable")
    return Calibration(min_qc, max_qc, zero_qc, settings.slope_deg_per_qc, settings.limit_deg)


_TXT = re.compile(r"^\s*(minValue|maxValue|zeroRef)\s*=\s*(-?\d+)\s*$", re.M)


def read_calibration_txt(path: str | Path) -> tuple[int, int, int]:
    """(min, max, zeroRef) from a calibration file the old code wrote next to its logs."""
    found = dict((k, int(v)) for k, v in _TXT.findall(Path(path).read_text()))
    missing = {"minValue", "maxValue", "zeroRef"} - set(found)
    if missing:
        raise CalibrationRefused(f"{path}: no {sorted(missing)[0]}")
    return found["minValue"], found["maxValue"], found["zeroRef"]


@dataclass
class SweepRecorder:
    """Follows the counter during a power-up sweep and says when it is complete.

    Feed it every position reading with its time; `done` turns true once the span is
    plausible and the wheel has come back near the middle and stayed still there.
    """
    settings: CalibrationSettings = field(default_factory=CalibrationSettings)
    min_qc: int | None = None
    max_qc: int | None = None
    last_qc: int | None = None
    last_t: float | None = None
    still_since: float | None = None
    problem: str = ""
    samples: int = 0

    def reset(self) -> None:
        self.min_qc = self.max_qc = self.last_qc = self.last_t = self.still_since = None
        self.problem = ""
        self.samples = 0

    def add(self, qc: int, t: float) -> None:
        s = self.settings
        if self.last_qc is not None and self.last_t is not None:     # (set together)
            allowed = s.max_jump_qc + s.max_hand_speed_qc_s * max(0.0, t - self.last_t)
            if abs(qc - self.last_qc) > allowed:
                last = self.last_qc
                self.reset()
                self.problem = f"counter jumped {last} -> {qc}: sweep restarted"
        lo = qc if self.min_qc is None else self.min_qc
        hi = qc if self.max_qc is None else self.max_qc
        self.min_qc, self.max_qc = min(lo, qc), max(hi, qc)
        if self.last_qc is None or abs(qc - self.last_qc) > s.still_qc:
            self.still_since = t
        self.last_qc, self.last_t = qc, t
        self.samples += 1
        if self.span_qc > s.max_span_qc:
            span = self.span_qc
            self.reset()
            self.problem = f"span {span} qc is more than lock to lock ({s.max_span_qc}): sweep restarted"

    @property
    def span_qc(self) -> int:
        return 0 if self.min_qc is None or self.max_qc is None else self.max_qc - self.min_qc

    def done(self, t: float) -> bool:
        s = self.settings
        if self.min_qc is None or self.max_qc is None or self.last_qc is None or self.span_qc < s.min_span_qc:
            return False
        back = abs(self.last_qc - zero_ref(self.min_qc, self.max_qc)) <= s.return_tolerance_qc
        return back and self.still_since is not None and t - self.still_since >= s.sweep_settle_s

    def result(self) -> Calibration:
        """The calibration this sweep gives, checked (CalibrationRefused otherwise)."""
        if self.min_qc is None or self.max_qc is None:
            raise CalibrationRefused("no position readings: the drive is not answering")
        return check_calibration(self.min_qc, self.max_qc, None, self.settings)

    def status(self) -> dict:
        return {"min_qc": self.min_qc, "max_qc": self.max_qc, "span_qc": self.span_qc,
                "problem": self.problem}
