"""The hijack probe of issue 24 against a person's client: a second pilot reads every sample
of the car while the owner steers with puts (which everyone who may subscribe receives) and
queries, and sends back whatever it can make of them. Setpoints are signed with a lease
that never travels, so not one of its setpoints is taken."""
from __future__ import annotations

import threading

import pytest
from test_steering_service import KEY, service, twin  # noqa: F401  (fixtures)
from vienatest import Hijacker, open_session

from viena.services.steering.client import SteeringClient

pytestmark = [pytest.mark.slow,  # a steering, its drive twin and a hijacker at its rate, with watchdogs:
              pytest.mark.car(seconds=30)]    # in the car lane, not beside another car

ROUNDS = 10
OWNER_DEG = 2.0


def test_a_second_pilot_who_sees_every_sample_steers_nothing(service, session, router):
    proc, latest, until = service
    owner = SteeringClient(session)
    arm = owner.arm()
    assert arm["status"] == "accepted", arm
    stop = threading.Event()

    def stream():                                    # puts at 20 Hz: what every subscriber receives
        while not stop.is_set():
            owner.put_setpoint(OWNER_DEG)
            stop.wait(0.05)

    streamer = threading.Thread(target=stream, daemon=True)
    with open_session(router) as other:
        mallory = Hijacker(other)
        streamer.start()
        try:
            mallory.hijack(ROUNDS)
        finally:
            stop.set()
            streamer.join(5)
            mallory.close()
    assert mallory.accepted == [], mallory.accepted[:2]
    assert not any(arm["lease"].encode() in raw for raw in mallory.raw)       # nor in any recording
    wanted = (arm["target_deg"], OWNER_DEG)           # where the arm held it, then the owner's angle
    goals = mallory.goals
    assert len(goals) > 20 and all(g is None or min(abs(g - w) for w in wanted) < 1e-6 for g in goals), \
        sorted(set(goals), key=str)
    assert until(lambda st: st["armed"] and st["owner"] == arm["owner"] and st["trip"] == ""), \
        {k: latest.get(k) for k in ("armed", "owner", "trip", "decision")}
    assert owner.setpoint(OWNER_DEG)["status"] in ("accepted", "clamped")     # the owner still steers
    assert owner.disarm()["status"] == "accepted"
    assert mallory.sent >= ROUNDS * 2 * 4 * 5
