"""How far and how fast the wheel may turn at a speed: the speed-scheduled envelope.

A car at speed v turning its front wheel to delta (the bicycle model, wheelbase L) has a
lateral acceleration a = v^2 tan(delta) / L, and turning the wheel at rate d(delta)/dt
gives a lateral jerk j = v^2 / (L cos^2 delta) d(delta)/dt. Limiting a and j gives

    the largest wheel angle      atan(a_max L / v^2)
    the fastest wheel rate       j_max L cos^2(delta) / v^2

both wide open when the car stands and tightening with v^2. The lateral acceleration is
and the jerk are scheduled by speed, as Autoware's vehicle_cmd_gate does: from 13 m/s the
driver-assist standards' 3 m/s^2 and 5 m/s^3 (ISO 11270 and ISO 15622), up to 10 m/s 7 m/s^2
and 15 m/s^3 (a campus loop's 12 m bends at 8 m/s need 5.3 m/s^2, and a tracker's turn into
them more, at a speed known to +-2 sigma), linear between: at 14 m/s the wheel may turn
1.7 deg, at 8 m/s 13.3 deg, at 4 m/s 44 deg (the range's end first; each less
`wheel_margin_deg`, what the calibration and the drive's following may be off).
The slew, the drive's mechanical rate, is scheduled too: from
`slew_deg_s` standing to `slew_top_deg_s` at top speed. For the first `engage_s` after an
arm a stricter pair holds (Autoware's vehicle_cmd_gate limits harder while engaging), so
taking the wheel never jerks the car.

One definition for everyone: the steering service enforces these limits on every target
(model/safety.py), and the pilot plans inside them (services/pilot), with the figures the
steering service gives in its arm reply (`as_dict`, `from_dict`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from viena.common.settings import setting

#: below this speed the car turns on the spot of a wheel: no lateral limit applies
STANDING_MPS = 0.1


#: the figures that are lists (a value per speed)
SCHEDULES = ("lateral_speeds_mps", "lateral_accel_mps2", "lateral_jerk_mps3")


@dataclass(frozen=True)
class LateralSettings:
    """The speed-scheduled limits on the wheel (docs/steering.md#the-speed-envelope)."""
    wheelbase_m: float = setting(2.2, "the car's wheelbase (the bicycle model's L)")
    lateral_speeds_mps: tuple[float, ...] = setting([10.0, 13.0], "the speeds the lateral limits are given at "
                                                    "(linear between, the ends held beyond)")
    lateral_accel_mps2: tuple[float, ...] = setting([7.0, 3.0], "largest lateral acceleration a target may "
                                                    "ask for, at each of lateral_speeds_mps")
    lateral_jerk_mps3: tuple[float, ...] = setting([15.0, 5.0], "largest lateral jerk the target's rate may "
                                                   "cause, at each of lateral_speeds_mps")
    engage_s: float = setting(1.0, "after an arm, the stricter engaging limits hold this long")
    engage_lateral_accel_mps2: float = setting(1.5, "largest lateral acceleration while engaging")
    engage_lateral_jerk_mps3: float = setting(2.5, "largest lateral jerk while engaging")
    wheel_margin_deg: float = setting(0.2, "the widest angle is narrowed by this much: how far the "
                                           "calibrated angle and the drive's following may be off the wheel's")
    slew_top_deg_s: float = setting(10.0, "the slew at top_speed_mps (slew_deg_s standing, linear between)")
    top_speed_mps: float = setting(15.0, "the car's top speed: where the slew schedule ends, and the speed "
                                         "assumed when it is not known")

    def scaled(self, share: float) -> LateralSettings:
        """The same envelope with every acceleration, jerk and top slew times `share`: what
        a client plans inside, to leave the steering room."""
        return replace(self, lateral_accel_mps2=tuple(share * a for a in self.lateral_accel_mps2),
                       lateral_jerk_mps3=tuple(share * j for j in self.lateral_jerk_mps3),
                       engage_lateral_accel_mps2=share * self.engage_lateral_accel_mps2,
                       engage_lateral_jerk_mps3=share * self.engage_lateral_jerk_mps3,
                       slew_top_deg_s=share * self.slew_top_deg_s)

    def as_dict(self) -> dict:
        """The figures, for the arm reply: what a client plans inside."""
        return asdict(self)

    @classmethod
    def from_dict(cls, figures: dict) -> LateralSettings:
        """The figures a steering service gave (unknown names ignored: a newer service may
        send more); ValueError if one is not a finite, non-negative number."""
        known = {f.name for f in fields(cls)}
        values: dict = {}
        for name in figures:
            if name in SCHEDULES:
                items = figures[name]
                if not isinstance(items, list | tuple) or not items:
                    raise ValueError(f"envelope figure {name}: {items!r} is not a list of numbers")
                values[name] = tuple(figure({name: x}, name) for x in items)
            elif name in known:
                values[name] = figure(figures, name)
        made = cls(**values)
        limits(0.0, made, 0.0)                   # the schedules as long as their speeds
        return made


def figure(figures: dict, name: str) -> float:
    """One figure of an envelope's: a finite, non-negative number, else ValueError."""
    value = figures.get(name)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError(f"envelope figure {name}: {value!r} is not a non-negative number")
    return float(value)


@dataclass(frozen=True)
class Limits:
    """The limits at one speed: the widest wheel angle either way, and the fastest rates."""
    speed_mps: float
    max_wheel_deg: float            # from the lateral acceleration (inf when standing)
    slew_deg_s: float               # the drive's scheduled rate
    lateral_accel_mps2: float
    lateral_jerk_mps3: float
    engaging: bool
    wheelbase_m: float

    def jerk_rate_deg_s(self, wheel_deg: float) -> float:
        """The fastest rate at `wheel_deg` that keeps the lateral jerk in its limit."""
        v2 = self.speed_mps * self.speed_mps
        if self.speed_mps < STANDING_MPS:
            return math.inf
        c = math.cos(math.radians(min(abs(wheel_deg), 89.0)))
        return math.degrees(self.lateral_jerk_mps3 * self.wheelbase_m * c * c / v2)

    def rate_deg_s(self, wheel_deg: float) -> float:
        """The fastest rate at `wheel_deg`: the slew, or the jerk's rate if slower."""
        return min(self.slew_deg_s, self.jerk_rate_deg_s(wheel_deg))


def limits(speed_mps: float, s: LateralSettings, slew_deg_s: float, engaging: bool = False) -> Limits:
    """The limits at `speed_mps` (a speed already judged: finite, >= 0); `slew_deg_s` is
    the standing slew (the envelope's own setting)."""
    v = max(0.0, speed_mps)
    accel = scheduled(v, s.lateral_speeds_mps, s.lateral_accel_mps2)
    jerk = scheduled(v, s.lateral_speeds_mps, s.lateral_jerk_mps3)
    if engaging:
        accel, jerk = min(accel, s.engage_lateral_accel_mps2), min(jerk, s.engage_lateral_jerk_mps3)
    if v < STANDING_MPS:
        wheel = math.inf
    else:
        wheel = max(0.0, math.degrees(math.atan(accel * s.wheelbase_m / (v * v))) - s.wheel_margin_deg)
    share = min(1.0, v / s.top_speed_mps) if s.top_speed_mps > 0 else 1.0
    slew = slew_deg_s + (min(s.slew_top_deg_s, slew_deg_s) - slew_deg_s) * share
    return Limits(v, wheel, slew, accel, jerk, engaging, s.wheelbase_m)


def scheduled(speed_mps: float, speeds: tuple[float, ...], values: tuple[float, ...]) -> float:
    """A limit scheduled by speed, as Autoware's gate does: linear between the given speeds,
    the first and last values held below and beyond them."""
    if not speeds or len(speeds) != len(values):
        raise ValueError(f"a schedule needs as many speeds as values: {speeds} and {values}")
    if speed_mps <= speeds[0]:
        return values[0]
    for (v0, a0), (v1, a1) in zip(zip(speeds, values), zip(speeds[1:], values[1:])):
        if speed_mps <= v1:
            return a0 + (a1 - a0) * (speed_mps - v0) / (v1 - v0) if v1 > v0 else a1
    return values[-1]


def lateral_accel_mps2(speed_mps: float, wheel_deg: float, wheelbase_m: float) -> float:
    """What the bicycle model says a wheel angle does at a speed: v^2 |tan delta| / L."""
    return speed_mps * speed_mps * abs(math.tan(math.radians(wheel_deg))) / wheelbase_m
