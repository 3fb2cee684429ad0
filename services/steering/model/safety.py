"""The steering safety envelope (docs/steering.md#the-envelope): what may reach the drive, and when to stop.

A plain class that is told the time (`now_s`, monotonic seconds; `wall_ns` for the
setpoints' own stamps) and never reads a clock, so every rule is testable without zenoh,
CAN or threads. It never talks to the drive: it answers what the target is, and whether
the watchdog has tripped; `core.SteeringCore` sends and stops.

- Rejected: a malformed setpoint (`requests.BadSetpoint`: not a map of known fields; a
  missing, non-numeric or non-finite angle; no code); one not signed with the owner's
  lease (model/signing.py), or replayed (its `seq` not above the last one taken); a stale
  timestamp; any setpoint while disarmed or tripped.
- Limited (the reply says "clamped" and which limit): the goal to the calibrated range
  minus a margin (`range`), and to the widest angle the car's speed allows
  (`lateral_accel`, model/lateral.py); each target sent to the drive to the slew since the
  previous one (`slew`, scheduled by speed), to the rate that keeps the lateral jerk in
  its limit (`lateral_jerk`), and to a set distance from the measured angle (`distance`).
  The target moves toward the goal on every tick, so one setpoint is enough to turn the
  wheel smoothly; the speed is the one model/speed.py trusts now, or the conservative one.
  A target left outside the lateral bound (the speed rose, or became unknown) goes back in
  at the slew, never further out.
- Watchdog: armed and no valid (accepted or clamped) setpoint for `watchdog_s` -> tripped;
  a new arm is required. Drive faults trip it too, with their cause (model/trips.py).

Invariants (tests/steering/test_steering_safety.py and test_steering_envelope.py check them
for any input and any speed): every target lies in the allowed range and moves by at most
the slew * dt from the one before; a target inside the lateral bound stays inside it and
moves at most at the jerk's rate; one outside it only moves back in.
"""
from __future__ import annotations

import hashlib
import hmac
import logging
import math
from dataclasses import dataclass, field

from viena.common import clock
from viena.common.settings import setting
from viena.services.steering.model.lateral import LateralSettings, Limits, limits
from viena.services.steering.model.requests import BadSetpoint, Setpoint
from viena.services.steering.model.signing import macs_match
from viena.services.steering.model.speed import Speed, SpeedSettings, SpeedSources
from viena.services.steering.model.trips import TripCause, trip_text

log = logging.getLogger("viena.steering.safety")

ACCEPTED, CLAMPED, REJECTED = "accepted", "clamped", "rejected"


@dataclass(frozen=True)
class SafetySettings:
    margin_deg: float = setting(1.0, "targets stay this far inside the calibrated range")
    slew_deg_s: float = setting(30.0, "fastest change of the target, standing (slew_top_deg_s at top speed)")
    #: how far the target may lead the measured angle (the drive faults at 0x6065)
    max_distance_deg: float = setting(4.0, "furthest the target may lead the measured angle")
    watchdog_s: float = setting(0.5, "armed and no valid setpoint this long: quick stop")
    #: a setpoint stamped (`t`, ns UTC) longer ago than this, or this far ahead, is stale
    max_age_s: float = setting(0.5, "a setpoint stamped longer ago, or further ahead, is stale")


@dataclass(frozen=True)
class Decision:
    """What happened to one setpoint; `target_deg` is what goes to the drive (None if nothing)."""
    status: str
    reason: str
    requested_deg: float | None = None
    target_deg: float | None = None
    goal_deg: float | None = None
    limits: tuple[str, ...] = ()
    speed_mps: float | None = None       # the speed the envelope used
    speed_source: str = ""


def lease_hash(lease: str | None) -> str | None:
    """What the state shows of a lease: enough to tell owners apart, useless to steal (the
    lease itself travels only in the arm's reply, to the one who armed)."""
    return None if lease is None else hashlib.sha256(lease.encode()).hexdigest()[:12]


@dataclass
class Envelope:
    settings: SafetySettings = field(default_factory=SafetySettings)
    lateral: LateralSettings = field(default_factory=LateralSettings)
    speed_settings: SpeedSettings = field(default_factory=SpeedSettings)

    def __post_init__(self):
        self.speeds = SpeedSources(self.speed_settings)
        self.armed_t: float | None = None    # when the owner armed (the engaging limits run from it)
        self._goal_used, self._goal_t = 0.0, 0.0   # the last goal as limited, and when: the rates' start
        self.used: tuple[Speed, Limits] | None = None   # the speed and limits the target was last made at
        self.range_deg: tuple[float, float] | None = None
        self.armed = False
        self.lease: str | None = None
        self.goal_deg: float | None = None
        self.target_deg: float | None = None
        self.target_t: float | None = None
        self.last_valid_t: float | None = None
        self.last_seq = -1                # the owner's last signed setpoint taken (replays refused)
        self.tripped = ""                 # why the last trip happened, as text ("" = none since arm)
        self.trip_cause: TripCause | None = None   # and its cause (None = none since arm)
        self.last: Decision | None = None
        self.refused: dict[str, int] = {}  # rejected setpoints by cause (REFUSAL_CAUSES), for health
        self._log = DecisionLog()
        self._limits_at: tuple | None = None   # (speed, engaging, lateral, slew, their Limits): the last made
        self._owner: tuple[str | None, str | None] = (None, None)   # (lease, its hash)

    # -- configuration -----------------------------------------------------------------------
    def set_range(self, lo_deg: float, hi_deg: float) -> None:
        """The calibrated range (before the margin); only while disarmed."""
        if self.armed:
            raise RuntimeError("the range cannot change while armed")
        if not (math.isfinite(lo_deg) and math.isfinite(hi_deg) and lo_deg < hi_deg):
            raise ValueError(f"bad range {lo_deg}..{hi_deg}")
        self.range_deg = (float(lo_deg), float(hi_deg))

    def clear_range(self) -> None:
        if self.armed:
            self.trip(TripCause.CALIBRATION_LOST)
        self.range_deg = None

    @property
    def allowed_deg(self) -> tuple[float, float] | None:
        """The range minus the margin on both sides: where targets may go."""
        if self.range_deg is None:
            return None
        lo, hi = self.range_deg[0] + self.settings.margin_deg, self.range_deg[1] - self.settings.margin_deg
        return (lo, hi) if lo < hi else None

    @property
    def calibrated_allowed_deg(self) -> tuple[float, float]:
        """`allowed_deg` where only a calibrated envelope gets (armed: `arm_refusal` checked it)."""
        allowed = self.allowed_deg
        if allowed is None:
            raise RuntimeError("the envelope has no calibrated range")
        return allowed

    @property
    def owner(self) -> str | None:
        if self._owner[0] != self.lease:        # hashed once per lease, not per state
            self._owner = (self.lease, lease_hash(self.lease))
        return self._owner[1]

    def limits_now(self, now_s: float) -> tuple[Speed, Limits]:
        """The speed trusted now, and the limits at it (the engaging ones for `engage_s`
        after an arm)."""
        speed = self.speeds.speed(now_s)
        engaging = self.armed and self.armed_t is not None and now_s - self.armed_t < self.lateral.engage_s
        made = self._limits_at                 # the same speed as last time: the same limits
        if made is not None and made[0] == speed.mps and made[1] == engaging and made[2] is self.lateral \
                and made[3] == self.settings.slew_deg_s:
            return speed, made[4]
        lim = limits(speed.mps, self.lateral, self.settings.slew_deg_s, engaging)
        self._limits_at = (speed.mps, engaging, self.lateral, self.settings.slew_deg_s, lim)
        return speed, lim

    # -- arming --------------------------------------------------------------------------
    def arm_refusal(self, measured_deg: float | None, lease: str | None = None) -> str | None:
        """Why an arm cannot happen now, or None if it can."""
        if self.armed and not (lease and self._is_owner(lease)):
            return "armed by another client"
        allowed = self.allowed_deg
        if allowed is None:
            return "not calibrated" if self.range_deg is None else "calibrated range is narrower than the margins"
        if measured_deg is None or not math.isfinite(measured_deg):
            return "no position from the drive"
        if not allowed[0] <= measured_deg <= allowed[1]:
            return (f"wheel at {measured_deg:.1f} deg is outside {allowed[0]:.1f}..{allowed[1]:.1f} deg: "
                    "turn it toward the centre by hand first")
        return None

    def arm(self, measured_deg: float, now_s: float, lease: str | None = None) -> str:
        """Take ownership; the target starts at the measured angle. Returns the lease."""
        refusal = self.arm_refusal(measured_deg, lease)
        if refusal:
            raise PermissionError(refusal)
        if not self.armed:
            self.lease = clock.token_urlsafe(16)   # unguessable on the car, the seed's in lockstep
            self.last_seq = -1
            self.goal_deg = self.target_deg = self._goal_used = float(measured_deg)
            self.target_t = self.armed_t = self._goal_t = now_s
        self.armed = True
        self.last_valid_t = now_s
        self.tripped, self.trip_cause = "", None
        log.info("armed by %s at %.2f deg", self.owner, measured_deg)
        return self._lease_held()

    def _lease_held(self) -> str:
        """The owner's lease, set by every arm."""
        if self.lease is None:
            raise RuntimeError("the envelope is not armed")
        return self.lease

    def disarm(self, lease: str | None) -> bool:
        """The owner gives the wheel back. False if `lease` is not the owner's."""
        if not self.armed or not lease or not self._is_owner(lease):
            return False
        log.info("disarmed by its owner %s", self.owner)
        self._release()
        return True

    def trip(self, cause: TripCause, detail: str = "") -> bool:
        """Stop: disarm with a cause (and the detail its text ends with); a new arm is needed.
        False if already disarmed."""
        was_armed = self.armed
        reason = trip_text(cause, detail)
        if was_armed or not self.tripped:
            self.tripped, self.trip_cause = reason, cause
        if was_armed:
            log.warning("tripped: %s (owner %s)", reason, self.owner)
        self._release()
        return was_armed

    def _release(self) -> None:
        self.armed = False
        self.lease = None
        self.goal_deg = None

    def _is_owner(self, lease) -> bool:
        return isinstance(lease, str) and self.lease is not None and \
            hmac.compare_digest(lease.encode(), self.lease.encode())

    # -- setpoints ---------------------------------------------------------------------------
    def setpoint(self, request: Setpoint | BadSetpoint, measured_deg: float | None,
                 now_s: float, wall_ns: int) -> Decision:
        """Judge one setpoint (`requests.parse_setpoint`) against the measured angle, at
        `now_s`; `wall_ns` is the host's UTC time, for the setpoint's own stamp."""
        self._watchdog(now_s)                # a late setpoint finds the wheel already given up
        decision = self._judge(request, measured_deg, now_s, wall_ns)
        self.last = decision
        self._log.record(decision, now_s)
        if decision.status == REJECTED:
            cause = "malformed" if isinstance(request, BadSetpoint) else refusal_cause(decision.reason)
            self.refused[cause] = self.refused.get(cause, 0) + 1
        return decision

    def _judge(self, request, measured_deg, now, wall_ns) -> Decision:
        if isinstance(request, BadSetpoint):
            return Decision(REJECTED, request.reason, request.requested_deg)
        requested = request.angle_deg
        absurd = self._absurd(requested)
        if absurd:
            return Decision(REJECTED, absurd, requested)
        if not self.armed:
            why = f"not armed ({self.tripped}): arm again" if self.tripped else "not armed"
            return Decision(REJECTED, why, requested)
        if not macs_match(request.signed_by(self.lease), request.mac):
            return Decision(REJECTED, "not signed with the owner's lease: another client holds the wheel",
                            requested)
        if request.seq <= self.last_seq:
            return Decision(REJECTED, f"replayed: seq {request.seq} is not above the last taken "
                                      f"({self.last_seq})", requested)
        stale = self._stale(request.t_ns, wall_ns)
        if stale:
            return Decision(REJECTED, stale, requested)
        self.last_seq = request.seq
        if measured_deg is None or not math.isfinite(measured_deg):
            return Decision(REJECTED, "no position from the drive", requested)
        lo, hi = self.calibrated_allowed_deg
        goal = min(max(requested, lo), hi)
        acted: tuple[str, ...] = ("range",) if goal != requested else ()
        previous, previous_t = self._goal_used, self._goal_t
        self.goal_deg = goal
        target, ramp, speed, lim = self._next_target(goal, measured_deg, now)
        self.last_valid_t = now
        goal = _within(goal, lim.max_wheel_deg)
        acted += tuple(k for k in ramp if k in ("lateral_accel", "distance"))
        # the rates judge the stream of goals, as a client sends them (the target between
        # them ramps at the same rates, tick by tick: the drive never moves faster)
        rate = lim.rate_deg_s(max(abs(previous), abs(goal)))
        if abs(goal - previous) > rate * (now - previous_t + RATE_SLACK_S):
            acted += ("slew" if rate >= lim.slew_deg_s else "lateral_jerk",)
        self._goal_used, self._goal_t = goal, now
        if acted:
            reason = "; ".join(_LIMIT_TEXT[k](self.settings, lo, hi, lim, target) for k in acted)
            if speed.problem:
                reason += f" (speed unknown: {speed.problem}; assumed {speed.mps:.1f} m/s)"
            return Decision(CLAMPED, reason, requested, target, goal, acted, lim.speed_mps, speed.source)
        return Decision(ACCEPTED, "", requested, target, goal, (), lim.speed_mps, speed.source)

    def _absurd(self, requested: float) -> str | None:
        """Finite but impossible: beyond twice the wheel's range is a bug, not a wish, and is
        refused rather than clamped to full lock."""
        reach = max(abs(a) for a in self.range_deg) if self.range_deg else ABSURD_UNCALIBRATED_DEG
        if abs(requested) > 2 * reach:
            return (f"absurd: {requested:.6g} deg is beyond twice the wheel's range "
                    f"(+-{reach:.0f} deg): refused, not clamped")
        return None

    def _stale(self, t_ns: int | None, wall_ns: int) -> str:
        if t_ns is None:
            return ""
        age = (wall_ns - t_ns) / 1e9
        if age > self.settings.max_age_s:
            return f"stale: stamped {age:.3f} s ago (limit {self.settings.max_age_s} s)"
        if age < -self.settings.max_age_s:
            return f"stamped {-age:.3f} s in the future: check the clocks"
        return ""

    # -- the periodic part ---------------------------------------------------------------
    def tick(self, measured_deg: float | None, now_s: float) -> tuple[float | None, str]:
        """Once per control period: (next target or None, trip reason or "")."""
        if not self.armed:
            return None, ""
        reason = self._watchdog(now_s)
        if reason:
            return None, reason
        if measured_deg is None or not math.isfinite(measured_deg):
            self.trip(TripCause.NO_POSITION)
            return None, self.tripped
        if self.goal_deg is None:                    # set by every arm and setpoint
            raise RuntimeError("armed without a goal")
        target = self._next_target(self.goal_deg, measured_deg, now_s)[0]
        return target, ""

    def _watchdog(self, now: float) -> str:
        """Trip if armed and silent for longer than the deadline; the reason, or ''."""
        if not self.armed or self.last_valid_t is None:     # every arm sets last_valid_t
            return ""
        silent = now - self.last_valid_t
        if silent <= self.settings.watchdog_s:
            return ""
        self.trip(TripCause.WATCHDOG, f": no valid setpoint for {silent:.3f} s")
        return self.tripped

    def _next_target(self, goal: float, measured: float, now: float) -> tuple[float, tuple[str, ...], Speed, Limits]:
        """Move the target toward `goal`: within the range and the lateral bound at the
        speed trusted now, at the slew or the jerk's rate since the last target (at the slew
        back inside the bound when it shrank), and as far as that allows near the measured
        angle. Returns the target, the limits that acted, the speed and its limits."""
        s = self.settings
        speed, lim = self.limits_now(now)
        lo, hi = self.calibrated_allowed_deg
        b_lo, b_hi = max(lo, -lim.max_wheel_deg), min(hi, lim.max_wheel_deg)
        if b_lo > b_hi:                              # a range that does not hold 0: its end nearest it
            b_lo = b_hi = lo if lo > 0 else hi
        if self.target_deg is None or self.target_t is None:     # set by every arm
            raise RuntimeError("armed without a target")
        prev, dt = self.target_deg, max(0.0, now - self.target_t)
        acted: tuple[str, ...] = ()
        wanted = min(max(goal, b_lo), b_hi)
        if wanted != goal and min(max(goal, lo), hi) == goal:
            acted += ("lateral_accel",)
        slew_step = lim.slew_deg_s * dt
        if prev > b_hi:                              # outside: back in at the slew, never further out
            win_lo, win_hi, rate_limit = max(b_lo, prev - slew_step), prev, "slew"
        elif prev < b_lo:
            win_lo, win_hi, rate_limit = prev, min(b_hi, prev + slew_step), "slew"
        else:
            jerk_rate = lim.jerk_rate_deg_s(max(abs(prev), abs(wanted)))
            # the distance clamp may take the target past `wanted` (toward the wheel): the
            # rate at the widest angle the window reaches, so no end of it turns too fast
            reach = abs(prev) + min(lim.slew_deg_s, jerk_rate) * dt
            jerk_rate = min(jerk_rate, lim.jerk_rate_deg_s(reach))
            rate_limit = "slew" if lim.slew_deg_s <= jerk_rate else "lateral_jerk"
            step = min(lim.slew_deg_s, jerk_rate) * dt
            win_lo, win_hi = max(b_lo, prev - step), min(b_hi, prev + step)
        target = min(max(wanted, win_lo), win_hi)
        if target != wanted:
            acted += (rate_limit,)
        near_lo, near_hi = measured - s.max_distance_deg, measured + s.max_distance_deg
        if not near_lo <= target <= near_hi:
            acted += ("distance",)
            both_lo, both_hi = max(win_lo, near_lo), min(win_hi, near_hi)
            if both_lo <= both_hi:
                target = min(max(target, both_lo), both_hi)
            else:                      # the wheel is far off: go toward it as fast as allowed
                target = win_hi if near_lo > win_hi else win_lo
        self.target_deg, self.target_t = target, now
        self.used = (speed, lim)
        return target, acted, speed, lim


def _within(angle_deg: float, bound_deg: float) -> float:
    return min(max(angle_deg, -bound_deg), bound_deg)


#: a goal may arrive this much sooner than its rate allows (a setpoint stream's jitter, a
#: control tick) before the rate is said to have acted
RATE_SLACK_S = 0.02

#: what a rejection is counted as: a fixed set, so a client's text never makes a new counter
REFUSAL_CAUSES = ("absurd", "not armed", "not signed", "replayed", "stale", "stamped", "no position")


def refusal_cause(reason: str) -> str:
    return next((cause for cause in REFUSAL_CAUSES if reason.startswith(cause)), "other")


_LIMIT_TEXT = {
    "range": lambda s, lo, hi, lim, target: f"range: limited to {lo:.1f}..{hi:.1f} deg",
    "lateral_accel": lambda s, lo, hi, lim, target: (
        f"lateral_accel: at most {lim.max_wheel_deg:.1f} deg at {lim.speed_mps:.1f} m/s "
        f"({lim.lateral_accel_mps2:g} m/s^2{', engaging' if lim.engaging else ''})"),
    "lateral_jerk": lambda s, lo, hi, lim, target: (
        f"lateral_jerk: turning at most {lim.jerk_rate_deg_s(target):.3g} deg/s at {lim.speed_mps:.1f} m/s "
        f"({lim.lateral_jerk_mps3:g} m/s^3{', engaging' if lim.engaging else ''})"),
    "slew": lambda s, lo, hi, lim, target: f"slew: {lim.slew_deg_s:.3g} deg/s at {lim.speed_mps:.1f} m/s",
    "distance": lambda s, lo, hi, lim, target: f"distance: at most {s.max_distance_deg:g} deg from the measured angle",
}


#: before calibration the range is unknown: no car's wheel turns 90 deg either way
ABSURD_UNCALIBRATED_DEG = 45.0


class DecisionLog:
    """Log each kind of decision once when it starts, with how often the previous repeated:
    a 50 Hz stream of accepted setpoints is one line, every change of verdict is seen. A
    kind seen again within `interval_s` is counted, not logged, so a flood of refusals (two
    clients alternating, 10,000 a second) costs one line per cause per interval."""

    def __init__(self, logger: logging.Logger = log, interval_s: float = 10.0):
        self._log = logger
        self.interval_s = interval_s
        self._key: tuple[str, str] | None = None
        self._repeats = 0
        self._logged_at: dict[tuple[str, str], float] = {}
        self._quiet: dict[tuple[str, str], int] = {}

    def record(self, d: Decision, now_s: float) -> None:
        key = (d.status, d.reason.split(":")[0])
        if key == self._key:
            self._repeats += 1
            return
        if self._repeats:
            self._log.info("(previous decision repeated %d more times)", self._repeats)
        self._key, self._repeats = key, 0
        last = self._logged_at.get(key)
        if last is not None and now_s - last < self.interval_s:
            self._quiet[key] = self._quiet.get(key, 0) + 1
            return
        self._logged_at[key] = now_s
        quiet = self._quiet.pop(key, 0)
        level = logging.WARNING if d.status == REJECTED else logging.INFO
        target = "" if d.target_deg is None else f" -> target {d.target_deg:.2f} deg"
        asked = "" if d.requested_deg is None else f" {d.requested_deg:.2f} deg"
        more = f" [{quiet} more like it since it was last logged]" if quiet else ""
        self._log.log(level, "setpoint%s %s%s%s%s", asked, d.status, f" ({d.reason})" if d.reason else "",
                      target, more)
