"""viena-pilot: follows a route of checkpoints by steering the car; the person drives the speed.

    viena-pilot [--controller pure_pursuit|stanley] [--setpoint-rate-hz 40] ...

Keys (relative to viena/<car>/; payloads JSON text or msgpack, replies in the question's):

- `pilot/route`, query or put: a route (docs/pilot.md#routes); a query without payload
  asks for the current one. Reply `{"status": "accepted", "route": <GeoJSON>, "mode"}` or
  `{"status": "rejected", "reason": ...}`.
- `pilot/cmd`, query or put: `{"cmd": "start"}` / `{"cmd": "stop"}` (or the bare word).
  Reply `{"status", "reason", "mode"}`.
- `pilot/state`, 20 Hz: `viena.pilot.state/1` (common/samples/pilot.py).
- `pilot/path`: `viena.pilot.path/1`, the route held, when taken and every 5 s (for
  recordings, plots and maps).

One control thread does everything in order at the setpoint rate: takes the routes and
commands read for it (inbox.py: a reader thread parses them, with size and depth bounds,
and answers every refusal, so a flood of malformed routes never reaches this thread),
reads the newest estimator and steering states, asks the model (model/pilot.py) for the
wheel angle, and streams it to the steering with its own lease (SteeringClient). The two
state streams (~100 and 50 Hz) are kept by zenoh in one-sample ring channels that the
thread reads when it needs them: no Python callback per sample, which is most of what such
a process would otherwise spend (docs/pilot.md#cost).
When the model says stop (or the steering refuses a setpoint), no more setpoints go out
and the lease is given back; the steering's watchdog is the last line if this process dies.
An estop put on steering/estop stops the pilot too (a flag, not a queued request: no
flood delays it); it then needs a new start, and a start sent before it is refused.

This module is the zenoh wiring (keys, channels, publishers) and the control thread's
loop; commands.py decides the routes, commands and estops; steering_link.py arms, sends
the setpoints, watches the steering and gives the lease back; delays.py keeps the
latencies health shows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import zenoh

from viena.common import clock
from viena.common.errors import ConfigError, InputError
from viena.common.keystore import PROGRAM_IDENTITY
from viena.common.log import Throttled
from viena.common.samples import topics
from viena.common.samples.pilot import path_sample
from viena.common.schema import unpack
from viena.common.service import Service, run_service
from viena.common.session import zenoh_options
from viena.common.settings import part, setting
from viena.services.pilot.commands import Commands
from viena.services.pilot.delays import Window
from viena.services.pilot.inbox import CMD, ROUTE, Inbox
from viena.services.pilot.model.estimate import estimate_of
from viena.services.pilot.model.pilot import Pilot, PilotSettings
from viena.services.pilot.model.precision import PrecisionSettings
from viena.services.pilot.model.safety import SafetySettings
from viena.services.pilot.model.tracking import TrackingSettings
from viena.services.pilot.steering_link import SteeringLink
from viena.services.steering.client import SteeringClient

#: who this process is on a secured car (a certificate of role `autopilot`, docs/pilot.md)
IDENTITY = PROGRAM_IDENTITY["pilot"]
#: how often the route held is published again on pilot/path
PATH_PERIOD_S = 5.0


@dataclass(frozen=True)
class PilotServiceSettings:
    """[pilot]: rates, keys, and the model's settings."""
    setpoint_rate_hz: float = setting(40.0, "setpoints per second while following (20-50)")
    state_rate_hz: float = setting(20.0, "pilot/state samples per second")
    estimate_key: str = setting(topics.ESTIMATOR_STATE.key(), "the estimator's state, key relative to `viena/<car>/`",
                                metavar="KEYEXPR")
    steering_timeout_s: float = setting(0.25, "longest wait for the steering's answer to a setpoint")
    arm_timeout_s: float = setting(3.0, "longest wait for the steering's answer to arm or disarm")
    steering_silence_s: float = setting(0.5, "setpoints unanswered, or no steering state, this long: stop "
                                             "(the steering's watchdog)")
    setpoints_as: str = setting("put", "put: cheap, refusals seen in steering/state; query: each one answered",
                                choices=("put", "query"))
    tracking: TrackingSettings = part(TrackingSettings, "turning the route into a wheel angle (model/tracking.py)")
    safety: SafetySettings = part(SafetySettings, "when to refuse or stop (model/safety.py)")
    precision: PrecisionSettings = part(PrecisionSettings, "which GNSS solution it follows with "
                                                           "(model/precision.py)")


class PilotService(Service):
    """Follows a route with pure pursuit (or Stanley), steering through its own lease."""

    name = "pilot"
    settings_class = PilotServiceSettings

    #: not `pilot`: that identity is a person's (viena keys init); this is the program
    identity = IDENTITY

    def __init__(self, args):
        super().__init__(args)
        self._refusals = Throttled(self.log, "refused")

    def start(self) -> None:
        s = self.settings
        if not 20.0 <= s.setpoint_rate_hz <= 50.0:
            raise ConfigError(f"[pilot] setpoint_rate_hz must be within 20..50, got {s.setpoint_rate_hz:g}")
        try:
            self.pilot = Pilot(PilotSettings(tracking=s.tracking, safety=s.safety, precision=s.precision))
        except ValueError as exc:
            raise ConfigError(f"[pilot]: {exc}") from None
        self.client = SteeringClient(self.session, self.keys.car, timeout_s=s.arm_timeout_s)
        self.inbox = Inbox(self.pilot, self.log, self.health, self.stopping)
        self._lateness = Window(self.health, "tick_late_ms")              # a tick's start after its time
        self._state_pub = self.publisher(topics.PILOT_STATE)
        self._path_pub = self.publisher(topics.PILOT_PATH)
        self._path_due = math.inf                     # when to publish the route again
        self._precise: bool | None = None             # the precision rule's verdict, as last logged
        for kind, topic in ((ROUTE, topics.PILOT_ROUTE), (CMD, topics.PILOT_CMD)):
            key = self.keys.of(topic)
            self.declare_queryable(key, self.inbox.on_query(kind, key, USAGE[kind]))
            self.declare_subscriber(key, self.inbox.on_put(kind))
        self._estimates = self.declare_subscriber(
            self.keys.key(s.estimate_key), zenoh.handlers.RingChannel(1))
        steering_states = None
        if s.setpoints_as == "put":
            steering_states = self.declare_subscriber(
                self.keys.of(topics.STEERING_STATE), zenoh.handlers.RingChannel(1))
        self.steering = SteeringLink(self.pilot, self.client, s, self.health, self.log, steering_states,
                                     self._put_estop)
        self.commands = Commands(self.pilot, self.inbox, self.steering, self.health, self.log, self._path_now)
        self.declare_subscriber(self.keys.of(topics.STEERING_ESTOP), self._on_estop)
        self.inbox.start()
        self._thread = clock.Thread(target=self._run, name="pilot", daemon=True)
        self._thread.start()
        self.log.info("pilot ready (%s), idle: send a route on %s", s.tracking.controller,
                      self.keys.of(topics.PILOT_ROUTE))

    def stop(self) -> None:
        self.stopping.set()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.join(timeout=1.5)
        inbox = getattr(self, "inbox", None)
        if inbox is not None:
            inbox.join(timeout_s=0.3)
        client = getattr(self, "client", None)
        if client is not None:
            client.close()

    def _on_estop(self, _sample: zenoh.Sample) -> None:
        """A zenoh callback: never blocks, never fails, whatever else is queued."""
        self.commands.on_estop()

    def _put_estop(self) -> None:
        self.session.put(self.keys.of(topics.STEERING_ESTOP), b"{}", **zenoh_options(topics.STEERING_ESTOP))

    def _path_now(self) -> None:
        self._path_due = 0.0

    # -- the control thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        period_s = 1.0 / self.settings.setpoint_rate_hz
        state_period_s = 1.0 / self.settings.state_rate_hz
        due = next_state = clock.monotonic()
        seq = 0
        try:
            while not self.stopping.is_set():
                self._lateness.add(clock.monotonic() - due)      # against the schedule: a slow step shows
                try:
                    self._step()
                except Exception:                        # noqa: BLE001 - never leave the wheel to chance
                    self.health.error("internal")
                    self.log.exception("pilot step failed: stopping")
                    self.pilot.stop("internal error (see the pilot's log)")
                    self.steering.give_back_lease()
                now = clock.monotonic()
                if now >= next_state:
                    next_state = max(next_state + state_period_s, now)
                    self._publish_state(seq)
                    seq += 1
                if now >= self._path_due and self.pilot.route is not None:
                    self._path_due = now + PATH_PERIOD_S
                    self._path_pub.put(path_sample(self.pilot.route, clock.time_ns()))
                # the next tick on schedule (a setpoint right after a late one still keeps the
                # router's spacing: the steering client waits it out, QUERY_SPACING_S)
                due += period_s
                if clock.monotonic() - due > period_s:          # fell a period behind: do not burst
                    due = clock.monotonic()
                self.stopping.wait(max(0.0, due - clock.monotonic()))
        finally:
            self.pilot.stop("pilot shut down")
            self.client.timeout_s = min(self.settings.arm_timeout_s, 0.5)   # within the 2 s stop
            self.steering.give_back_lease()

    def _step(self) -> None:
        self._read_estimate()
        if self.settings.setpoints_as == "put":
            self.steering.read_state()
        self.commands.decide()
        before = self.pilot.mode
        # armed before the angle is made: the pilot plans from the steering's target and limits
        if self.pilot.mode == "following" and self.client.lease is None and not self.steering.arm():
            return
        angle_rad = self.pilot.tick(clock.time_ns())
        if angle_rad is None:
            if self.pilot.mode != before:
                self.log.info("%s: %s", self.pilot.mode, self.pilot.reason)
            self.steering.give_back_lease()
            return
        self.steering.setpoint(math.degrees(angle_rad))

    def _read_estimate(self) -> None:
        """The newest estimator state, if one came since the last tick."""
        sample = self._estimates.try_recv()
        if sample is None:
            return
        try:
            self.pilot.on_estimate(estimate_of(unpack(sample.payload.to_bytes(), "estimator state")))
            self.health.count("estimate")
        except InputError as exc:
            self.health.error("bad_estimate")
            self._refusals.log("estimate", f"estimator state not used: {exc}")

    def _publish_state(self, seq: int) -> None:
        state = self.pilot.snapshot(clock.time_ns(), seq, self.client.lease is not None)
        if self._state_pub.put(state):
            self.health.count("state")
            self.health.mark_sample()
        self.health.set("mode", state["mode"])
        self.health.set("reason", state["reason"])
        self.health.set("precision", "ok" if state["precision_ok"] else state["precision_reason"])
        rule = self.settings.precision
        if state["precision_ok"] != self._precise and rule.min_solution != "none":
            self._precise = state["precision_ok"]
            if self._precise:
                self.log.info("precision: %s is good enough to follow by", state["precision_kind"])
            else:
                self.log.warning("precision: %s (%s)", state["precision_reason"],
                                 "stops the pilot" if rule.on_imprecise == "stop" else "warning only")


USAGE = {
    "route": "a route as a query or put (GeoJSON, point list, Titans checkpoints, CSV); "
             "a query without payload: the current route",
    "cmd": '{"cmd": "start"} or {"cmd": "stop"}, as a query or a put',
}


def main(argv: list[str] | None = None) -> int:
    return run_service(PilotService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
