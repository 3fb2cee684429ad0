"""The hijack probe of issue 24 against the autopilot: while it follows a route, a second
pilot reads every sample of the car (the autopilot's setpoint puts among them) and sends
back whatever it can make of them. Before, it put -25 deg under the autopilot's lease and
the wheel followed it while the autopilot still reported `following`; now the setpoints
are signed with a lease that never travels, and not one of the hijacker's is taken."""
from __future__ import annotations

import pytest
from test_pilot_service import CAR, car, following, start_pilot  # noqa: F401  (fixtures)
from vienatest import Hijacker, open_session, wait_for_subscriber, wait_until

from viena.services.steering.model.state import STATE as STEERING_STATE

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # a pilot and a steering, with watchdogs

ROUNDS = 10
HIJACK_DEG = -25.0


def test_a_second_pilot_cannot_steer_under_the_autopilots_lease(procs, router, session, car):
    start_pilot(procs, router, car["config"], session)
    following(session, car)
    owner = car["steering"].value["owner"]
    goals: list[float | None] = []
    watch = session.declare_subscriber(
        f"{CAR}/steering/state", lambda s: goals.append(STEERING_STATE.decode(s.payload.to_bytes())["goal_deg"]))
    with open_session(router) as other:
        mallory = Hijacker(other, angle_deg=HIJACK_DEG)
        try:
            assert wait_for_subscriber(session, f"{CAR}/steering/setpoint")
            assert wait_until(lambda: len(mallory.setpoints) >= 5, 10.0), "the autopilot's puts were not seen"
            for _ in range(ROUNDS):
                assert mallory.attack() > 0
        finally:
            mallory.close()
            watch.undeclare()
    assert mallory.accepted == [], mallory.accepted[:2]
    assert len(goals) > 20 and not any(g is not None and g < 0 for g in goals), sorted(set(goals), key=str)
    assert car["steering"].until(lambda st: st["armed"] and st["owner"] == owner and st["trip"] == "")
    assert car["pilot"].until(lambda st: st["mode"] == "following" and st["wheel_cmd_deg"] > 0)
