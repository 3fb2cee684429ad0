"""The safety envelope on a simulated clock: for any sequence of inputs, what reaches the
drive stays inside the range and the slew limit, silence trips the watchdog, and nobody
but the owner steers."""
from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vienatest import signed

from viena.services.steering.model.requests import parse_setpoint
from viena.services.steering.model.safety import (
    ACCEPTED,
    CLAMPED,
    REJECTED,
    DecisionLog,
    Envelope,
    SafetySettings,
    lease_hash,
)
from viena.services.steering.model.speed import SpeedSettings
from viena.services.steering.model.trips import TripCause, trip_text

RANGE = (-29.0, 29.0)
PERIOD = 0.01                         # the control loop's tick
SAFE = SafetySettings()               # margin 1 deg, slew 30 deg/s, distance 4 deg, watchdog 0.5 s
#: a drive on a bench: no speed source, and none assumed (test_steering_envelope.py has the speeds)
BENCH = SpeedSettings(speed_conservative_mps=0.0)


WALL_NS = 1_700_000_000_000_000_000  # the host's UTC time, for the setpoints' own stamps


class FakeClock:
    def __init__(self, t: float = 100.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


class Timed:
    """An envelope and the simulated time it is told: `clock.t += dt` between calls."""

    def __init__(self, env: Envelope, clock: FakeClock):
        self.env, self.clock = env, clock

    def __getattr__(self, name):
        return getattr(self.env, name)

    def arm(self, measured_deg, lease=None):
        return self.env.arm(measured_deg, self.clock.t, lease)

    def setpoint(self, payload, measured_deg):
        """`payload` as its sender would send it: signed with the lease it names."""
        return self.env.setpoint(parse_setpoint(signed(payload)), measured_deg, self.clock.t, WALL_NS)

    def raw_setpoint(self, payload, measured_deg):
        """`payload` exactly as given (a replay, a forgery)."""
        return self.env.setpoint(parse_setpoint(payload), measured_deg, self.clock.t, WALL_NS)

    def tick(self, measured_deg):
        return self.env.tick(measured_deg, self.clock.t)

    def wall_ns(self) -> int:
        return WALL_NS


def make_envelope(clock=None, **kw) -> Timed:
    env = Envelope(SafetySettings(**kw) if kw else SAFE, speed_settings=BENCH)
    env.set_range(*RANGE)
    return Timed(env, clock or FakeClock())


# -- plain rules --------------------------------------------------------------------------
def test_a_setpoint_inside_the_envelope_is_accepted_and_becomes_the_target():
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    clock.t += 0.1
    d = env.setpoint({"angle_deg": 2.0, "lease": lease}, measured_deg=0.0)
    assert (d.status, d.target_deg, d.limits) == (ACCEPTED, 2.0, ())


@pytest.mark.parametrize("payload, reason", [
    ({"angle_deg": float("nan")}, "not finite"),
    ({"angle_deg": float("inf")}, "not finite"),
    ({"angle_deg": 10 ** 400}, "not finite"),
    ({"angle_rad": 1e308}, "not finite"),
    ({"angle_deg": "5"}, "must be a number"),
    ({"angle_deg": True}, "must be a number"),
    ({"angle_deg": None}, "must be a number"),
    ({}, "missing angle_deg"),
    ({"angle_deg": 1.0, "angle_rad": 0.1}, "not both"),
    ({"angle_deg": 1.0, "speed": 3}, "unknown field 'speed'"),
    ({"angle_deg": 1.0, "arm": True}, "unknown field 'arm'"),
])
def test_malformed_setpoints_are_rejected_with_the_reason(payload, reason):
    env = make_envelope()
    lease = env.arm(0.0)
    d = env.setpoint({**payload, "lease": lease}, measured_deg=0.0)
    assert d.status == REJECTED and reason in d.reason and d.target_deg is None


def test_unsigned_foreign_or_unarmed_setpoints_are_rejected():
    env = make_envelope()
    assert "not armed" in env.setpoint({"angle_deg": 1.0, "lease": "x"}, 0.0).reason
    lease = env.arm(0.0)
    assert "missing mac" in env.setpoint({"angle_deg": 1.0, "seq": 1}, 0.0).reason
    assert "not signed with the owner's lease" in env.setpoint({"angle_deg": 1.0, "lease": lease + "x"}, 0.0).reason
    assert "mac must be text" in env.raw_setpoint({"angle_deg": 1.0, "seq": 1, "mac": 7}, 0.0).reason
    assert "seq must be an integer" in env.raw_setpoint({"angle_deg": 1.0, "seq": "x", "mac": "00"}, 0.0).reason
    assert env.setpoint({"angle_deg": 0.0, "lease": lease}, 0.0).status == ACCEPTED


def test_a_setpoint_carrying_the_lease_itself_is_refused_even_from_the_owner():
    """The lease never goes on the wire after the arm's reply: a client that sends it has
    given it to everyone who can read the key (every pilot and observer, every recording)."""
    env = make_envelope()
    lease = env.arm(0.0)
    d = env.raw_setpoint({"angle_deg": 1.0, "lease": lease}, 0.0)
    assert d.status == REJECTED and "never carries the lease" in d.reason


def test_whoever_sees_the_owners_setpoints_can_neither_replay_nor_alter_them():
    """What a second pilot reads on steering/setpoint (or in a recording) is angles, counters
    and codes: sent again it is a replay, changed it no longer matches its code."""
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    seen = signed({"angle_deg": 1.0, "lease": lease})
    clock.t += 0.05
    assert env.raw_setpoint(seen, 0.0).status == ACCEPTED
    clock.t += 0.05
    replay = env.raw_setpoint(seen, 0.0)
    assert replay.status == REJECTED and "replayed" in replay.reason
    for forged in ({**seen, "angle_deg": 20.0}, {**seen, "seq": seen["seq"] + 1},
                   {**seen, "t": WALL_NS}, {**seen, "angle_rad": 1.0, "angle_deg": None}):
        forged = {k: v for k, v in forged.items() if v is not None}
        d = env.raw_setpoint(forged, 0.0)
        assert d.status == REJECTED and "not signed with the owner's lease" in d.reason, (forged, d)
    older = signed({"angle_deg": 2.0, "lease": lease, "seq": seen["seq"] - 1})
    assert "replayed" in env.raw_setpoint(older, 0.0).reason
    assert env.target_deg == pytest.approx(1.0) and env.armed
    assert env.refused == {"replayed": 2, "not signed": 4}                     # counted by cause for health


def test_stale_and_future_stamps_are_rejected():
    env = make_envelope()
    lease = env.arm(0.0)
    now = env.wall_ns()
    assert env.setpoint({"angle_deg": 0.0, "lease": lease, "t": now - 10 ** 8}, 0.0).status == ACCEPTED
    assert "stale" in env.setpoint({"angle_deg": 1.0, "lease": lease, "t": now - 2 * 10 ** 9}, 0.0).reason
    assert "future" in env.setpoint({"angle_deg": 1.0, "lease": lease, "t": now + 2 * 10 ** 9}, 0.0).reason
    assert "integer time" in env.setpoint({"angle_deg": 1.0, "lease": lease, "t": 1.5}, 0.0).reason
    stale = signed({"angle_deg": 1.0, "lease": lease, "t": now - 2 * 10 ** 9})
    assert "stale" in env.raw_setpoint(stale, 0.0).reason
    assert env.raw_setpoint({**stale, "t": now}, 0.0).status == REJECTED     # a fresh stamp on it: forged


def test_beyond_the_range_is_clamped_to_the_range_minus_the_margin():
    clock = FakeClock()
    env = make_envelope(clock, max_distance_deg=90.0, slew_deg_s=1e6)
    lease = env.arm(0.0)
    clock.t += 0.4
    d = env.setpoint({"angle_deg": 45.0, "lease": lease}, measured_deg=0.0)
    assert d.status == CLAMPED and d.limits == ("range",) and d.target_deg == 28.0
    assert "range" in d.reason


def test_a_step_is_slewed_and_the_ticks_carry_the_target_to_the_goal():
    clock = FakeClock()
    env = make_envelope(clock, max_distance_deg=90.0)
    lease = env.arm(0.0)
    clock.t += 0.1
    d = env.setpoint({"angle_deg": 10.0, "lease": lease}, measured_deg=0.0)
    assert d.status == CLAMPED and d.limits == ("slew",) and d.target_deg == pytest.approx(3.0)
    assert d.goal_deg == 10.0
    for _ in range(10):
        clock.t += 0.03
        target, tripped = env.tick(measured_deg=0.0)
        assert not tripped
    assert target == pytest.approx(10.0)


def test_the_target_does_not_run_away_from_the_measured_wheel():
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    clock.t += 0.4                      # slew would allow 12 deg
    d = env.setpoint({"angle_deg": 20.0, "lease": lease}, measured_deg=0.0)
    assert d.status == CLAMPED and "distance" in d.limits and d.target_deg == pytest.approx(4.0)


def test_watchdog_trips_after_the_deadline_and_needs_a_new_arm():
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    clock.t += 0.49
    assert env.tick(0.0) == (0.0, "")
    clock.t += 0.02
    target, tripped = env.tick(0.0)
    assert target is None and tripped == env.tripped == trip_text(TripCause.WATCHDOG, ": no valid setpoint for 0.510 s")
    assert not env.armed and env.trip_cause is TripCause.WATCHDOG
    d = env.setpoint({"angle_deg": 1.0, "lease": lease}, 0.0)
    assert d.status == REJECTED and "arm again" in d.reason
    new = env.arm(0.0)
    assert new != lease and env.setpoint({"angle_deg": 1.0, "lease": lease}, 0.0).status == REJECTED


def test_rejected_setpoints_do_not_feed_the_watchdog():
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    for _ in range(5):
        clock.t += 0.1
        env.setpoint({"angle_deg": float("nan"), "lease": lease}, 0.0)
    clock.t += 0.01
    assert env.tick(0.0)[1] and env.trip_cause is TripCause.WATCHDOG and not env.armed


def test_a_second_client_can_neither_arm_nor_disarm_nor_steer():
    env = make_envelope()
    owner = env.arm(0.0)
    with pytest.raises(PermissionError, match="another client"):
        env.arm(0.0)
    assert env.arm_refusal(0.0, "guess") == "armed by another client"
    assert not env.disarm("guess") and env.armed
    assert env.setpoint({"angle_deg": 3.0, "lease": "guess"}, 0.0).status == REJECTED
    assert env.disarm(owner) and not env.armed


def test_arming_is_refused_uncalibrated_or_with_the_wheel_outside():
    env = Envelope(SAFE, speed_settings=BENCH)
    assert env.arm_refusal(0.0) == "not calibrated"
    env.set_range(*RANGE)
    assert "outside" in env.arm_refusal(28.5)
    assert env.arm_refusal(float("nan")) == "no position from the drive"
    assert env.arm_refusal(27.9) is None


def test_the_state_shows_a_hash_of_the_lease_not_the_lease():
    env = make_envelope()
    lease = env.arm(0.0)
    assert env.owner == lease_hash(lease) and lease not in env.owner and len(env.owner) == 12


def test_each_kind_of_decision_is_logged_once(caplog):
    clock = FakeClock()
    env = make_envelope(clock)
    lease = env.arm(0.0)
    with caplog.at_level("INFO", logger="viena.steering.safety"):
        for _ in range(20):
            clock.t += 0.01
            env.setpoint({"angle_deg": 0.1, "lease": lease}, 0.0)
        env.setpoint({"angle_deg": "x", "lease": lease}, 0.0)
    lines = [r.getMessage() for r in caplog.records]
    assert sum("accepted" in line for line in lines) == 1
    assert any("repeated 19 more times" in line for line in lines)
    assert any("rejected" in line and "must be a number" in line for line in lines)
    assert isinstance(DecisionLog(), DecisionLog)


# -- properties ---------------------------------------------------------------------------
angles = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-60, max_value=60),
    st.integers(min_value=-10 ** 30, max_value=10 ** 30),
    st.text(max_size=5), st.none(), st.booleans(), st.lists(st.integers(), max_size=2))

setpoint_payloads = st.one_of(
    st.fixed_dictionaries({"angle_deg": angles, "lease": st.just("OWNER")}),
    st.fixed_dictionaries({"angle_rad": angles, "lease": st.just("OWNER")}),
    st.fixed_dictionaries({"angle_deg": angles, "lease": st.one_of(st.text(max_size=8), st.integers(), st.none())}),
    st.fixed_dictionaries({"angle_deg": angles, "seq": st.integers(-2, 2 ** 64), "mac": st.text(max_size=33)}),
    st.fixed_dictionaries({"angle_deg": angles}),
    st.dictionaries(st.text(max_size=6), st.one_of(angles, st.just("OWNER")), max_size=4),
    st.one_of(st.text(max_size=5), st.integers(), st.none(), st.lists(st.integers(), max_size=3)),
)

events = st.one_of(
    st.tuples(st.just("setpoint"), setpoint_payloads, st.floats(-40, 40)),
    st.tuples(st.just("burst"), st.fixed_dictionaries({"angle_deg": st.floats(-60, 60), "lease": st.just("OWNER")}),
              st.integers(2, 20)),
    st.tuples(st.just("wait"), st.floats(0.0, 1.2), st.floats(-40, 40)),
    st.tuples(st.just("arm"), st.floats(-30, 30), st.none()),
    st.tuples(st.just("intruder"), st.floats(-60, 60), st.none()),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(events, min_size=1, max_size=60), st.floats(0.5, 10.0))
def test_for_any_input_the_drive_only_sees_targets_inside_the_envelope(script, measured_lag):
    """Targets stay in range and within the slew; every silence longer than the deadline
    trips the watchdog (and nothing shorter does); another client never steers."""
    clock = FakeClock()
    env = make_envelope(clock)
    lo, hi = RANGE[0] + SAFE.margin_deg, RANGE[1] - SAFE.margin_deg
    owner = None
    measured = 0.0
    sent: list[tuple[float, float]] = []          # (time, target) since the current arm
    last_valid = None

    def emit(target):
        assert lo - 1e-9 <= target <= hi + 1e-9, f"target {target} outside {lo}..{hi}"
        if sent:
            t0, prev = sent[-1]
            assert abs(target - prev) <= SAFE.slew_deg_s * (clock.t - t0) + 1e-9, \
                f"slew: {prev} -> {target} in {clock.t - t0} s"
        sent.append((clock.t, target))

    def tick():
        nonlocal last_valid, measured
        armed_before = env.armed
        target, tripped = env.tick(measured)
        if tripped:
            assert armed_before and clock.t - last_valid > SAFE.watchdog_s, "early trip"
        if armed_before and not tripped:
            assert clock.t - last_valid <= SAFE.watchdog_s, "late trip"
        if target is not None:
            emit(target)
            measured += (target - measured) * min(1.0, PERIOD * measured_lag)

    def send(payload, wheel):
        nonlocal last_valid
        by_owner = isinstance(payload, dict) and payload.get("lease") == "OWNER" and owner is not None
        if by_owner:
            payload = {**payload, "lease": owner}
        late = env.armed and clock.t - last_valid > SAFE.watchdog_s
        d = env.setpoint(payload, wheel)           # signed with the lease the payload names
        if late:
            assert not env.armed and d.status == REJECTED, "a setpoint after the deadline was taken"
        if d.status in (ACCEPTED, CLAMPED):
            assert by_owner, f"taken without the owner's signature: {payload}"
            last_valid = clock.t
        else:
            assert d.target_deg is None
        if d.target_deg is not None:
            emit(d.target_deg)

    for kind, a, b in script:
        if kind == "setpoint":
            send(a, b)
        elif kind == "burst":
            for _ in range(b):
                send(a, measured)
        elif kind == "wait":
            end = clock.t + a
            while clock.t + PERIOD <= end:
                clock.t += PERIOD
                tick()
            clock.t = end
        elif kind == "arm":
            if env.armed:
                with pytest.raises(PermissionError):
                    env.arm(a)
                continue
            measured = a
            if env.arm_refusal(a) is None:
                owner = env.arm(a)
                sent.clear()
                last_valid = clock.t
                emit(env.target_deg)
        elif kind == "intruder":
            before = env.target_deg
            d = env.setpoint({"angle_deg": a, "lease": "intruder"}, measured)
            assert d.status == REJECTED and env.target_deg == before
            assert not env.disarm("intruder")
        if not env.armed:
            sent.clear()
    assert not math.isnan(clock.t)
