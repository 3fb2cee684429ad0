"""The hijack probe of issue 24 against the autopilot: while it follows a route, a second
pilot reads every sample of the car (the autopilot's setpoint puts among them) and sends
back whatever it can make of them. Before, it put -25 deg under the autopilot's lease and
the wheel followed it while the autopilot still reported `following`; now the setpoints
are signed with a lease that never travels, and not one of the hijacker's is taken."""
from __future__ import annotations

import pytest
from test_pilot_service import CAR, car, following, start_pilot  # noqa: F401  (fixtures)
from vienatest import Hijacker, open_session

pytestmark = [pytest.mark.slow,  # a pilot and a steering, with watchdogs, and a hijacker:
              pytest.mark.car(seconds=30)]    # in the car lane, not beside another car

ROUNDS = 10
HIJACK_DEG = -25.0


def test_a_second_pilot_cannot_steer_under_the_autopilots_lease(procs, router, session, car):
    start_pilot(procs, router, car["config"], session)
    following(session, car)
    owner = car["steering"].value["owner"]
    with open_session(router) as other:
        mallory = Hijacker(other, angle_deg=HIJACK_DEG)
        try:
            mallory.hijack(ROUNDS)
        finally:
            mallory.close()
    assert mallory.accepted == [], mallory.accepted[:2]
    goals = mallory.goals
    assert len(goals) > 20 and not any(g is not None and g < 0 for g in goals), sorted(set(goals), key=str)
    assert car["steering"].until(lambda st: st["armed"] and st["owner"] == owner and st["trip"] == "")
    assert car["pilot"].until(lambda st: st["mode"] == "following" and st["wheel_cmd_deg"] > 0)
