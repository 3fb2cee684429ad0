"""The pilot's side of the steering, run by the control thread: the lease (arm, give back),
the setpoints (put, judged by the steering's state; or queries, each answered), and the
stops they lead to: the steering refused, stopped steering for us, or went silent.

A put setpoint is judged by the newest steering state, read at most one tick after it
arrived; a query setpoint by its answer. A lost answer is not a refusal: setpoints keep
going until the steering's own watchdog would have given up on us (`steering_silence_s`).
Someone else answering the steering's keys stops the pilot and puts an estop.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from viena.common import clock
from viena.common.errors import InputError
from viena.common.health import Health
from viena.common.samples.steering import STATE as STEERING_STATE
from viena.common.schema import unpack
from viena.services.pilot.delays import Window
from viena.services.pilot.inbox import ACCEPTED, REJECTED
from viena.services.pilot.model.pilot import Pilot
from viena.services.steering.client import ConflictingReplies, SteeringClient

if TYPE_CHECKING:
    from viena.services.pilot.service import PilotServiceSettings

_STEERING = STEERING_STATE.reader("armed", "owner", "trip", "speed_mps")
#: steering states arriving this soon after the arm may predate it
ARM_MARGIN_S = 0.1


class SteeringLink:
    """Steers for `pilot` through `client`'s lease (see the module's docstring). `states` is
    the steering state's one-sample channel (setpoints as puts), `estop` puts an estop."""

    def __init__(self, pilot: Pilot, client: SteeringClient, settings: PilotServiceSettings, health: Health,
                 log: logging.Logger, states: Any, estop: Callable[[], None]):
        self.pilot, self.client, self.settings = pilot, client, settings
        self.health, self.log = health, log
        self._states, self._estop = states, estop
        self._latencies = Window(health, "estimate_to_setpoint_ms")  # estimate's stamp -> setpoint sent
        self._unanswered_since: float | None = None
        self._steering: tuple | None = None           # (read monotonic, armed, owner, trip)
        self._owner: str | None = None
        self._armed_at = 0.0                           # monotonic, when the arm was granted

    def read_state(self) -> None:
        """The newest steering state, if one came since the last tick; stamped with when it
        was read, at most one tick after it arrived."""
        sample = self._states.try_recv()
        if sample is None:
            return
        try:
            armed, owner, trip, speed = _STEERING(unpack(sample.payload.to_bytes(), "steering state"))
        except InputError:
            self.health.error("bad_steering_state")
            return
        self._steering = (clock.monotonic(), armed, owner, trip)
        self.pilot.steering_speed_mps = speed

    def arm(self) -> bool:
        try:
            reply = self.client.arm()
        except ConflictingReplies as exc:
            return self._conflict(exc)
        if reply.get("status") != ACCEPTED or not self.client.lease:
            self.pilot.stop(f"steering refused to arm: {reply.get('reason', reply.get('status'))}")
            self.log.warning("stopped: %s", self.pilot.reason)
            return False
        try:
            self.pilot.on_armed(reply.get("envelope"), clock.time_ns(), reply.get("target_deg"))
        except (ValueError, TypeError) as exc:
            self.pilot.stop(f"steering's envelope unreadable: {exc}")
            self.log.warning("stopped: %s", self.pilot.reason)
            self._owner = reply.get("owner")
            self.give_back_lease()
            return False
        self._owner, self._armed_at = reply.get("owner"), clock.monotonic()
        self.health.count("armed")
        self.log.info("armed: following the route")
        return True

    def setpoint(self, angle_deg: float) -> None:
        if self.settings.setpoints_as == "put":
            self._setpoint_put(angle_deg)
            return
        try:
            reply = self.client.setpoint(angle_deg, timeout_s=self.settings.steering_timeout_s)
        except ConflictingReplies as exc:
            self._conflict(exc)
            return
        self.health.count("setpoint")
        est = self.pilot.estimate
        assert est is not None, "a setpoint is made from an estimate"
        self._latencies.add((clock.time_ns() - est.t_ns) * 1e-9)
        now = clock.monotonic()
        if str(reply.get("reason", "")).startswith("no answer"):
            # a lost answer is not a refusal: keep streaming, until the steering's own
            # watchdog would have given up on us anyway
            self.health.error("setpoint_unanswered")
            self._unanswered_since = self._unanswered_since or now
            if now - self._unanswered_since < self.settings.steering_silence_s:
                return
        else:
            self._unanswered_since = None
        if reply.get("status") == REJECTED:
            self.pilot.stop(f"steering refused a setpoint: {reply.get('reason')}")
            self.log.warning("stopped: %s", self.pilot.reason)
            self.give_back_lease()

    def _setpoint_put(self, angle_deg: float) -> None:
        """Put the setpoint; the steering's state says whether it still steers for us."""
        steering = self._steering
        now = clock.monotonic()
        why = None
        if steering is None or now - steering[0] > self.settings.steering_silence_s:
            self._unanswered_since = self._unanswered_since or now
            if now - self._unanswered_since >= self.settings.steering_silence_s:
                why = "no steering state: is viena-steering running?"
        else:
            self._unanswered_since = None
            received, armed, owner, trip = steering
            # judged by when it arrived here (not its stamp: the steering may run on another
            # machine's clock), with a margin for a state already on its way at the arm
            if received > self._armed_at + ARM_MARGIN_S and not (armed and owner == self._owner):
                why = f"steering stopped: {trip or 'disarmed'}"
        if why is not None:
            self.pilot.stop(why)
            self.log.warning("stopped: %s", why)
            self.client.lease = None if why.startswith("steering stopped") else self.client.lease
            self.give_back_lease()
            return
        self.client.put_setpoint(angle_deg)
        self.health.count("setpoint")
        # From the estimate's stamp to the setpoint made from it sent (or answered, for
        # queries). The stamp is the estimator's clock: on one machine, or machines kept in
        # sync, it is the whole way from the sensors' time to the steering.
        est = self.pilot.estimate
        assert est is not None, "a setpoint is made from an estimate"
        self._latencies.add((clock.time_ns() - est.t_ns) * 1e-9)

    def give_back_lease(self) -> None:
        """No more setpoints, then disarm (a lease the steering already dropped is simply
        forgotten: its answer says so)."""
        if self.client.lease is None:
            return
        try:
            reply = self.client.disarm()
        except ConflictingReplies as exc:
            self._conflict(exc)
            return
        self.log.info("disarmed: %s", reply.get("status"))

    def _conflict(self, exc: ConflictingReplies) -> bool:
        """Someone else answers the steering keys: stop, estop, and trust nothing."""
        self.pilot.stop(f"steering answered by more than one process: {exc}")
        self.log.error("%s: estop", exc)
        self.client.lease, self.client.replier = None, None
        self._estop()
        return False
