"""The speed-aware envelope (issue 26) on a simulated clock: whatever the commands and
whatever the speed sources say, no target leaves the envelope at the speed the envelope
trusts at that moment.

The property test plays random drives: a true speed that accelerates, brakes and cruises;
an estimator and GNSS receivers that report it (with noise), fall silent, disagree, or
send bad samples (NaN, negative, 200 m/s, stamped in the future or the past); the owner's
setpoints at random times (1 ms .. 0.2 s apart, beyond the range too), the control
tick every 10 ms, a drive that follows the target with a lag (or is knocked off it), and
re-arms (the engaging limits). After every setpoint and every tick it checks, at the
limits `env.limits_now` gives for that moment:

- the target is in the allowed range;
- it moved at most the scheduled slew * dt;
- from inside the lateral bound (|angle| <= atan(a L / v^2)) it stays inside, moving at
  most the jerk's rate (at the widest angle it passed) * dt;
- from outside (the speed rose, or became unknown) it never goes further out.
"""
from __future__ import annotations

import logging
import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_steering_safety import WALL_NS, FakeClock, Timed

from viena.services.steering.model.lateral import LateralSettings, lateral_accel_mps2, limits
from viena.services.steering.model.safety import ACCEPTED, CLAMPED, REJECTED, Envelope, SafetySettings
from viena.services.steering.model.speed import CONSERVATIVE, SpeedSettings
from viena.services.steering.model.trips import TripCause

PERIOD = 0.01                      # the control loop's tick
EPS = 1e-9
LATERAL = LateralSettings()        # 2.2 m; 7 m/s^2 and 15 m/s^3 to 8 m/s, 3 and 5 from 13; engaging 1.5 and 2.5
SPEEDS = SpeedSettings()           # 0.5 s timeout, 15 m/s conservative
T0 = 100.0                         # FakeClock's start: WALL_NS is the host's UTC time then


def wall_ns(t: float) -> int:
    return WALL_NS + round((t - T0) * 1e9)


def make_envelope(clock: FakeClock, range_deg=(-29.0, 29.0), **speed_kw) -> Timed:
    env = Envelope(SafetySettings(), LATERAL, SpeedSettings(**speed_kw) if speed_kw else SPEEDS)
    env.set_range(*range_deg)
    return Timed(env, clock)


def feed_estimator(env: Timed, speed_mps: float, sigma_mps: float = 0.1, age_s: float = 0.0) -> str:
    now = env.clock.t
    return env.speeds.estimator(wall_ns(now - age_s), speed_mps, sigma_mps, True, now, wall_ns(now))


def feed_gnss(env: Timed, unit: str, speed_mps: float, sigma_mps: float = 0.1) -> str:
    now = env.clock.t
    return env.speeds.gnss(unit, wall_ns(now), speed_mps, sigma_mps, True, now, wall_ns(now))


# -- the invariants ---------------------------------------------------------------------------
class Violation(AssertionError):
    pass


def check_step(env: Timed, prev: float, prev_t: float, new: float, now: float, what: str):
    """The envelope's invariants for one move of the target, at the limits of `now`;
    returns the speed and the limits."""
    speed, lim = env.limits_now(now)
    lo, hi = env.allowed_deg
    dt = now - prev_t
    at = (f"{what} at t={now - T0:.3f}: {prev!r} -> {new!r} in {dt:.4f} s at {speed.mps:.3f} m/s "
          f"({speed.source}{', engaging' if lim.engaging else ''})")
    if not lo - EPS <= new <= hi + EPS:
        raise Violation(f"range: {at} is outside {lo}..{hi}")
    if abs(new - prev) > lim.slew_deg_s * dt + EPS:
        raise Violation(f"slew: {at} is faster than {lim.slew_deg_s} deg/s")
    b_lo, b_hi = max(lo, -lim.max_wheel_deg), min(hi, lim.max_wheel_deg)
    if b_lo <= prev <= b_hi:
        if not b_lo - EPS <= new <= b_hi + EPS:
            raise Violation(f"lateral_accel: {at} leaves the bound {b_lo:.4f}..{b_hi:.4f}")
        rate = lim.jerk_rate_deg_s(max(abs(prev), abs(new)))
        if abs(new - prev) > rate * dt + EPS:
            raise Violation(f"lateral_jerk: {at} is faster than {rate:.4f} deg/s")
    elif abs(new) > abs(prev) + EPS:
        raise Violation(f"outside the bound {b_lo:.4f}..{b_hi:.4f}: {at} goes further out")
    return speed, lim


# -- plain cases ----------------------------------------------------------------------------------
def drive(env: Timed, seconds: float, angle_deg: float, speed_mps: float | None, sigma_mps: float = 0.05,
          setpoint_hz: float = 20.0):
    """Steer for `seconds` of simulated time: the control tick every 10 ms, the estimator's
    speed at 50 Hz (none if `speed_mps` is None), the owner's `angle_deg` at `setpoint_hz`; the
    drive follows the target exactly. Returns the steps as (t, kind, target, decision or None),
    each checked against the invariants."""
    clock = env.clock
    steps = []
    prev, prev_t = env.target_deg, clock.t
    every = round(100 / setpoint_hz)
    for k in range(1, round(seconds / PERIOD) + 1):
        clock.t += PERIOD
        if speed_mps is not None and k % 2 == 0:
            assert feed_estimator(env, speed_mps, sigma_mps) == ""
        if k % every == 0:
            d = env.setpoint({"angle_deg": angle_deg, "lease": env.lease}, prev)
            assert d.status in (ACCEPTED, CLAMPED), d
            check_step(env, prev, prev_t, d.target_deg, clock.t, "setpoint")
            prev, prev_t = d.target_deg, clock.t
            steps.append((clock.t, "setpoint", prev, d))
        target, tripped = env.tick(prev)
        assert not tripped
        check_step(env, prev, prev_t, target, clock.t, "tick")
        prev, prev_t = target, clock.t
        steps.append((clock.t, "tick", prev, None))
    return steps


def test_the_issues_case_25_deg_at_13_9_mps_is_held_to_3_mps2_and_the_reply_says_why():
    """Issue 26: `viena-steer --angle-deg 25 --seconds 4` at 13.9 m/s gave 40.6 m/s^2."""
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 13.9, 0.05)
    env.arm(0.0)
    steps = drive(env, 4.0, 25.0, 13.9)
    worst = max(lateral_accel_mps2(13.9, target, LATERAL.wheelbase_m) for _t, _k, target, _d in steps)
    assert worst <= 3.0 + 1e-9
    replies = [d for _t, kind, _target, d in steps if kind == "setpoint"]
    assert len(replies) == 80
    for d in replies:
        assert d.status == CLAMPED and "lateral_accel" in d.limits, d
        assert d.speed_source == "estimator" and d.speed_mps == pytest.approx(14.0)   # 13.9 + 2 sigma
        assert f"at {d.speed_mps:.1f} m/s" in d.reason and "lateral_accel: at most" in d.reason, d.reason
    bound = limits(14.0, LATERAL, SafetySettings().slew_deg_s).max_wheel_deg
    assert steps[-1][2] == pytest.approx(bound) and bound < 2.0          # the wheel went to 1.9 deg, not 25


def test_engaging_limits_hold_for_the_first_second_after_an_arm_then_relax():
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 8.0, 0.05)
    armed_t = clock.t
    env.arm(0.0)
    assert env.limits_now(armed_t + 0.5)[1].engaging and not env.limits_now(armed_t + LATERAL.engage_s + 0.01)[1].engaging
    steps = drive(env, 3.0, 25.0, 8.0)
    v = 8.1                                                                  # 8 + 2 sigma
    engaging = limits(v, LATERAL, SafetySettings().slew_deg_s, engaging=True)
    normal = limits(v, LATERAL, SafetySettings().slew_deg_s)
    assert engaging.max_wheel_deg < normal.max_wheel_deg
    early = [(t, target, d) for t, _k, target, d in steps if t - armed_t < LATERAL.engage_s]
    assert max(target for _t, target, _d in early) <= engaging.max_wheel_deg + 1e-9
    assert max(lateral_accel_mps2(v, target, LATERAL.wheelbase_m) for _t, target, _d in early) <= 1.5 + 1e-9
    said = [d for _t, _target, d in early if d is not None]
    assert said and all("engaging" in d.reason for d in said)
    later = [d for t, _k, _target, d in steps if d is not None and t - armed_t > LATERAL.engage_s + 0.02]
    assert later and not any("engaging" in d.reason for d in later)
    assert steps[-1][2] == pytest.approx(normal.max_wheel_deg)               # relaxed to the normal bound


def test_the_estimator_lost_at_a_wide_angle_brings_the_target_back_in_at_the_slew_never_further_out():
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 3.0, 0.05)
    env.arm(0.0)
    drive(env, 2.0, 20.0, 3.0)
    assert env.target_deg == pytest.approx(20.0)
    silent_t = clock.t                                                       # its last sample was just now
    steps = drive(env, 3.0, 20.0, None)
    timeout = SPEEDS.speed_timeout_s
    conservative = limits(SPEEDS.speed_conservative_mps, LATERAL, SafetySettings().slew_deg_s)
    for (t0, _k0, before, _d0), (t, _k, target, d) in zip(steps, steps[1:]):
        assert abs(target) <= abs(before) + 1e-12                            # never further out
        speed = env.speeds.speed(t)
        if t - silent_t <= timeout:
            assert speed.source == "estimator"
            continue
        assert speed.source == CONSERVATIVE and speed.mps == SPEEDS.speed_conservative_mps
        if before > conservative.max_wheel_deg and t > t0:
            assert before - target == pytest.approx(min(before - conservative.max_wheel_deg,
                                                        conservative.slew_deg_s * (t - t0)))
        if d is not None:
            assert d.speed_source == CONSERVATIVE and "speed unknown: no fresh speed from the estimator" in d.reason
    back_in = next(t for t, _k, target, _d in steps if target <= conservative.max_wheel_deg + 1e-9)
    assert back_in - silent_t == pytest.approx(timeout + (20.0 - conservative.max_wheel_deg) / 10.0, abs=0.02)
    assert steps[-1][2] == pytest.approx(conservative.max_wheel_deg)


def test_bad_speed_samples_are_refused_counted_and_the_conservative_speed_used():
    clock = FakeClock(T0)
    env = make_envelope(clock)
    now, wall = clock.t, wall_ns(clock.t)
    est, gnss = env.speeds.estimator, env.speeds.gnss
    assert est(wall, math.nan, 0.1, True, now, wall) == "non_finite"
    assert est(wall, -3.0, 0.1, True, now, wall) == "negative"
    assert est(wall, 200.0, 0.1, True, now, wall) == "absurd"
    assert est(wall + 10 ** 9, 5.0, 0.1, True, now, wall) == "future"
    assert est(wall - 10 ** 9, 5.0, 0.1, True, now, wall) == "stale"
    assert gnss("gnss0", wall, math.inf, 0.1, True, now, wall) == "non_finite"
    assert gnss("gnss0", wall, 5.0, 0.1, False, now, wall) == "not_valid"
    assert env.speeds.refused == {"non_finite": 2, "negative": 1, "absurd": 1, "future": 1, "stale": 1,
                                  "not_valid": 1}
    lease = env.arm(0.0)
    clock.t += 0.05
    d = env.setpoint({"angle_deg": 10.0, "lease": lease}, 0.0)
    assert (d.speed_source, d.speed_mps) == (CONSERVATIVE, SPEEDS.speed_conservative_mps)
    assert "no speed from the estimator yet" in d.reason
    assert lateral_accel_mps2(SPEEDS.speed_conservative_mps, d.target_deg, LATERAL.wheelbase_m) <= 1.5 + 1e-9


def test_sources_that_disagree_give_the_conservative_speed_and_say_why():
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 4.0, 0.1)
    feed_gnss(env, "gnss0", 9.0, 0.1)
    speed, lim = env.limits_now(clock.t)
    assert (speed.source, speed.mps) == (CONSERVATIVE, SPEEDS.speed_conservative_mps)
    assert "disagree" in speed.problem and "4.0 m/s" in speed.problem and "9.0 m/s" in speed.problem
    lease = env.arm(0.0)
    clock.t += 0.05
    d = env.setpoint({"angle_deg": 10.0, "lease": lease}, 0.0)
    assert d.speed_source == CONSERVATIVE and "disagree" in d.reason


def test_sources_that_agree_give_the_higher_speed_and_name_both():
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 10.0, 0.1)                     # 10.2 with its margin
    feed_gnss(env, "gnss0", 10.3, 0.15)                # 10.6 with its margin
    speed, lim = env.limits_now(clock.t)
    assert speed.source == "estimator+gnss0" and speed.mps == pytest.approx(10.6) and not speed.problem
    assert lim.speed_mps == pytest.approx(10.6)


def test_a_target_turned_toward_the_wheel_moves_at_the_jerks_rate_at_the_angle_it_reaches():
    """What the property test found (invariant `lateral_jerk`; its smallest case: holding 0
    deg at 3.6 m/s, engaging, the wheel knocked off by a kerb): a wheel more than
    max_distance_deg off the target takes the target toward it, past the goal, at the jerk's
    rate of the goal's angle rather than the (slower) one of the wider angle it ends at."""
    clock = FakeClock(T0)
    env = make_envelope(clock)
    feed_estimator(env, 10.0, 0.0)
    env.arm(0.0)
    drive(env, 2.0, 5.0, 10.0)
    assert env.target_deg == pytest.approx(5.0)
    prev, prev_t = env.target_deg, clock.t
    clock.t += PERIOD
    feed_estimator(env, 10.0, 0.0)
    target, _ = env.tick(10.0)                          # the wheel knocked 5 deg out by a kerb
    check_step(env, prev, prev_t, target, clock.t, "tick")


# -- random drives ------------------------------------------------------------------------------
#: what the true speed does in a segment, what the sources do, what the owner asks for
TRUTH = ("accelerate", "brake", "cruise", "stop")
SOURCES = ("normal", "normal", "estimator_lost", "all_lost", "gnss_disagrees", "bad_samples", "two_receivers",
           "stale_stamps")
COMMANDS = ("hold", "random", "sine", "bang", "small", "beyond")
BAD = ("nan", "negative", "absurd", "future", "stale", "inf", "sigma_nan", "not_valid")

segments = st.tuples(
    st.sampled_from(TRUTH),
    st.floats(0.3, 6.0),                     # seconds
    st.floats(0.0, 4.0),                     # how hard (m/s^2)
    st.sampled_from(SOURCES),
    st.sampled_from(COMMANDS),
    st.floats(-60.0, 60.0),                  # the command's size
    st.booleans(),                           # re-arm at the start of the segment
    st.integers(0, 2 ** 32 - 1),             # the seed for the segment's many small draws
)

TOTALS = {"setpoints": 0, "ticks": 0, "speed samples": 0, "refused samples": 0, "violations": 0,
          "conservative steps": 0, "outside the bound": 0, "examples": 0}


class Drive:
    """One random drive through the envelope, checked at every step."""

    def __init__(self, range_deg, v0: float):
        self.clock = FakeClock(T0)
        self.env = make_envelope(self.clock, range_deg)
        self.v = v0                          # the true speed
        self.measured = 0.0
        self.owner = self.env.arm(0.0)
        self.prev, self.prev_t = self.env.target_deg, self.clock.t

    def run(self, segment) -> None:
        truth, seconds, accel, sources, commands, size, rearm, seed = segment
        rng = random.Random(seed)
        env, clock = self.env, self.clock
        if rearm or not env.armed:
            self._rearm()
        start, end = clock.t, clock.t + seconds
        lost = (start + rng.uniform(0, seconds / 2), start + rng.uniform(seconds / 2, seconds + 2.0))
        offset = rng.choice((-1, 1)) * rng.uniform(2.0, 10.0)
        lag = rng.uniform(0.05, 1.0)
        sigma = rng.uniform(0.0, 0.5)
        next_cmd = clock.t + self._interval(rng)
        next_tick = clock.t + PERIOD
        next_est, next_gnss = clock.t + rng.uniform(0, 0.02), clock.t + rng.uniform(0, 0.1)
        k = 0
        while True:
            t = min(next_cmd, next_tick, next_est, next_gnss)
            if t > end:
                break
            self._advance(truth, accel, t - clock.t)
            clock.t = t
            if t == next_est:
                next_est += 0.02
                if sources != "all_lost" and not (sources == "estimator_lost" and lost[0] <= t < lost[1]):
                    self._sample("estimator", self._noisy(rng, sigma), sigma, rng, sources)
            elif t == next_gnss:
                next_gnss += 0.1
                if sources != "all_lost":
                    v = self.v + (offset if sources == "gnss_disagrees" else 0.0)
                    self._sample("gnss0", max(0.0, v + rng.gauss(0, 0.1)), 0.15, rng, sources)
                    if sources == "two_receivers":
                        self._sample("gnss1", max(0.0, self.v + rng.gauss(0, 0.3)), 0.3, rng, sources)
            elif t == next_cmd:
                next_cmd += self._interval(rng)
                k += 1
                self._setpoint(self._command(commands, size, k, t - start, rng))
            else:
                next_tick += PERIOD
                self._tick(lag, rng)

    # -- the world --------------------------------------------------------------------------
    def _advance(self, truth: str, accel: float, dt: float) -> None:
        a = {"accelerate": accel, "brake": -1.5 * accel, "cruise": 0.0, "stop": -6.0}[truth]
        self.v = min(16.0, max(0.0, self.v + a * dt))

    @staticmethod
    def _interval(rng: random.Random) -> float:
        return math.exp(rng.uniform(math.log(0.001), math.log(0.2)))     # 1 ms .. 0.2 s, log-uniform

    def _noisy(self, rng: random.Random, sigma: float) -> float:
        return self.v + rng.gauss(0, sigma)          # may go negative near a stop: refused, as it should be

    @staticmethod
    def _command(commands: str, size: float, k: int, t: float, rng: random.Random) -> float:
        if commands == "hold":
            return size
        if commands == "random":
            return rng.uniform(-45, 45)
        if commands == "sine":
            return size * math.sin(2 * math.pi * 0.5 * t)
        if commands == "bang":
            return size if (k // 3) % 2 else -size
        if commands == "small":
            return rng.gauss(0, 2.0)
        return math.copysign(rng.uniform(29.0, 58.0), size)           # beyond the range

    def _sample(self, unit: str, speed: float, sigma: float, rng: random.Random, sources: str) -> None:
        now = self.clock.t
        stamp, valid = wall_ns(now - rng.uniform(0, 0.03)), True
        if sources == "bad_samples" and rng.random() < 0.4:
            bad = rng.choice(BAD)
            speed = {"nan": math.nan, "negative": -abs(speed) - 0.1, "absurd": 200.0, "inf": math.inf}.get(bad, speed)
            sigma = math.nan if bad == "sigma_nan" else sigma
            valid = bad != "not_valid"
            stamp = {"future": wall_ns(now + 1.0), "stale": wall_ns(now - 1.0)}.get(bad, stamp)
        elif sources == "stale_stamps" and rng.random() < 0.5:
            stamp = wall_ns(now - rng.uniform(0.5, 3.0))
        speeds = self.env.speeds
        feed = speeds.estimator if unit == "estimator" else \
            (lambda *a: speeds.gnss(unit, *a))
        why = feed(stamp, speed, sigma, valid, now, wall_ns(now))
        TOTALS["speed samples"] += 1
        TOTALS["refused samples"] += bool(why)

    # -- the envelope -------------------------------------------------------------------------
    def _rearm(self) -> None:
        env = self.env
        if env.armed:
            env.disarm(self.owner)
        if env.arm_refusal(self.measured) is None:
            self.owner = env.arm(self.measured)
        else:                                        # knocked outside the range: wheel it back by hand
            self.measured = 0.0
            self.owner = env.arm(0.0)
        self.prev, self.prev_t = env.target_deg, self.clock.t

    def _setpoint(self, angle: float) -> None:
        before = self.env.target_deg
        d = self.env.setpoint({"angle_deg": angle, "lease": self.owner}, self.measured)
        TOTALS["setpoints"] += 1
        if d.status == REJECTED:
            if self.env.armed:                       # beyond twice the range: refused, not clamped
                assert d.reason.startswith("absurd") and self.env.target_deg == before, d
            else:                                    # only absurd ones for the watchdog's deadline
                assert self.env.trip_cause is TripCause.WATCHDOG, (d, self.env.tripped)
                self._rearm()
            return
        self._check(d.target_deg, "setpoint")

    def _tick(self, lag: float, rng: random.Random) -> None:
        target, tripped = self.env.tick(self.measured)
        if tripped:                                  # only absurd setpoints for the watchdog's deadline
            assert self.env.trip_cause is TripCause.WATCHDOG, tripped
            self._rearm()
            return
        self._check(target, "tick")
        TOTALS["ticks"] += 1
        self.measured += (target - self.measured) * lag
        if rng.random() < 0.002:                     # the wheel knocked off the target (a kerb)
            self.measured += rng.uniform(-8.0, 8.0)

    def _check(self, new: float, what: str) -> None:
        now = self.clock.t
        try:
            speed, lim = check_step(self.env, self.prev, self.prev_t, new, now, what)
        except Violation:
            TOTALS["violations"] += 1
            raise
        TOTALS["conservative steps"] += speed.source == CONSERVATIVE
        TOTALS["outside the bound"] += abs(new) > lim.max_wheel_deg + EPS
        self.prev, self.prev_t = new, now


@pytest.fixture
def quiet():
    """No decision log: a hundred thousand steps' worth of it is slow to capture."""
    logger = logging.getLogger("viena.steering.safety")
    level = logger.level
    logger.setLevel(logging.ERROR)
    yield
    logger.setLevel(level)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(segments, min_size=1, max_size=14),
       st.sampled_from([(-29.0, 29.0), (-20.0, 35.0), (-35.0, 12.0), (-3.0, 3.0)]),
       st.floats(0.0, 16.0))
def _random_drives(script, range_deg, v0):
    TOTALS["examples"] += 1
    drive = Drive(range_deg, v0)
    for segment in script:
        drive.run(segment)


@pytest.mark.slow
def test_for_any_commands_and_speeds_no_target_leaves_the_envelope(quiet):
    for key in TOTALS:
        TOTALS[key] = 0
    _random_drives()
    steps = TOTALS["setpoints"] + TOTALS["ticks"]
    print(f"\nenvelope properties: {steps} steps ({TOTALS['setpoints']} setpoints, {TOTALS['ticks']} ticks) "
          f"in {TOTALS['examples']} drives; {TOTALS['speed samples']} speed samples "
          f"({TOTALS['refused samples']} refused); {TOTALS['conservative steps']} steps at the conservative "
          f"speed, {TOTALS['outside the bound']} outside the bound; violations: {TOTALS['violations']}")
    assert TOTALS["violations"] == 0
    assert steps >= 100_000 and TOTALS["setpoints"] >= 20_000
    assert TOTALS["conservative steps"] and TOTALS["outside the bound"] and TOTALS["refused samples"]
