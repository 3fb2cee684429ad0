"""viena-pilot: follows a route of checkpoints by steering the car; the person drives the speed.

    viena-pilot [--controller pure_pursuit|stanley] [--setpoint-rate-hz 40] ...

Keys (relative to viena/<car>/; payloads JSON text or msgpack, replies in the question's):

- `pilot/route`, query or put: a route (docs/pilot.md#routes); a query without payload
  asks for the current one. Reply `{"status": "accepted", "route": <GeoJSON>, "mode"}` or
  `{"status": "rejected", "reason": ...}`.
- `pilot/cmd`, query or put: `{"cmd": "start"}` / `{"cmd": "stop"}` (or the bare word).
  Reply `{"status", "reason", "mode"}`.
- `pilot/state`, 20 Hz: `viena.pilot.state/1` (model/state.py).
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import zenoh

from viena.common import clock
from viena.common.errors import ConfigError, InputError
from viena.common.log import Throttled
from viena.common.schema import unpack
from viena.common.service import Service, run_service
from viena.common.session import zenoh_config
from viena.common.settings import part, setting
from viena.services.pilot.inbox import ACCEPTED, CMD, REJECTED, ROUTE, Inbox, Request
from viena.services.pilot.model.estimate import estimate_of
from viena.services.pilot.model.pilot import IDLE, Pilot, PilotSettings
from viena.services.pilot.model.precision import PrecisionSettings
from viena.services.pilot.model.route import RouteError
from viena.services.pilot.model.safety import SafetySettings
from viena.services.pilot.model.state import PATH, STATE, path_sample
from viena.services.pilot.model.tracking import TrackingSettings
from viena.services.steering.client import ConflictingReplies, SteeringClient
from viena.services.steering.model.state import STATE as STEERING_STATE

#: who this process is on a secured car (a certificate of role `autopilot`, docs/pilot.md)
IDENTITY = "autopilot"
_STEERING = STEERING_STATE.reader("armed", "owner", "trip", "speed_mps")
#: steering states arriving this soon after the arm may predate it
ARM_MARGIN_S = 0.1
#: how often the route held is published again on pilot/path
PATH_PERIOD_S = 5.0


@dataclass(frozen=True)
class PilotServiceSettings:
    """[pilot]: rates, keys, and the model's settings."""
    setpoint_rate_hz: float = setting(40.0, "setpoints per second while following (20-50)")
    state_rate_hz: float = setting(20.0, "pilot/state samples per second")
    estimate_key: str = setting("estimator/state", "the estimator's state, key relative to `viena/<car>/`",
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

    def __init__(self, args):
        super().__init__(args)
        # not `pilot`: that identity is a person's (viena keys init); this is the program
        self.zenoh_config = zenoh_config(args, self.toml, identity=IDENTITY)
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
        self._estop = clock.Event()                    # an estop put came: stop at the next tick
        self._estop_number = 0                         # and refuse a start that came before it
        self._unanswered_since: float | None = None
        self._latencies = Window(self.health, "estimate_to_setpoint_ms")  # estimate's stamp -> setpoint sent
        self._lateness = Window(self.health, "tick_late_ms")              # a tick's start after its time
        self._state_pub = self.publisher(self.keys.key("pilot", "state"), STATE)
        self._path_pub = self.publisher(self.keys.key("pilot", "path"), PATH)
        self._path_due = math.inf                     # when to publish the route again
        self._precise: bool | None = None             # the precision rule's verdict, as last logged
        for kind in (ROUTE, CMD):
            key = self.keys.key("pilot", kind)
            self.declare_queryable(key, self.inbox.on_query(kind, key, USAGE[kind]))
            self.declare_subscriber(key, self.inbox.on_put(kind))
        self._estimates = self.declare_subscriber(
            self.keys.key(s.estimate_key), zenoh.handlers.RingChannel(1))
        self._steering: tuple | None = None           # (read monotonic, armed, owner, trip)
        self._owner: str | None = None
        self._armed_at = 0.0                           # monotonic, when the arm was granted
        if s.setpoints_as == "put":
            self._steering_states = self.declare_subscriber(
                self.keys.key("steering", "state"), zenoh.handlers.RingChannel(1))
        self.declare_subscriber(self.keys.key("steering", "estop"), self._on_estop)
        self.inbox.start()
        self._thread = clock.Thread(target=self._run, name="pilot", daemon=True)
        self._thread.start()
        self.log.info("pilot ready (%s), idle: send a route on %s", s.tracking.controller,
                      self.keys.key("pilot", "route"))

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
        self._estop_number = self.inbox.number()
        self._estop.set()

    # -- the control thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        period_s = 1.0 / self.settings.setpoint_rate_hz
        state_period_s = 1.0 / self.settings.state_rate_hz
        next_tick = next_state = clock.monotonic()
        seq = 0
        try:
            while not self.stopping.is_set():
                self._lateness.add(clock.monotonic() - next_tick)
                try:
                    self._step()
                except Exception:                        # noqa: BLE001 - never leave the wheel to chance
                    self.health.error("internal")
                    self.log.exception("pilot step failed: stopping")
                    self.pilot.stop("internal error (see the pilot's log)")
                    self._give_back_lease()
                now = clock.monotonic()
                if now >= next_state:
                    next_state = max(next_state + state_period_s, now)
                    self._publish_state(seq)
                    seq += 1
                if now >= self._path_due and self.pilot.route is not None:
                    self._path_due = now + PATH_PERIOD_S
                    self._path_pub.put(path_sample(self.pilot.route, clock.time_ns()))
                next_tick += period_s
                self.stopping.wait(max(0.0, next_tick - clock.monotonic()))
                if clock.monotonic() - next_tick > period_s:     # fell behind: do not burst
                    next_tick = clock.monotonic()
        finally:
            self.pilot.stop("pilot shut down")
            self.client.timeout_s = min(self.settings.arm_timeout_s, 0.5)   # within the 2 s stop
            self._give_back_lease()

    def _step(self) -> None:
        self._read_estimate()
        if self.settings.setpoints_as == "put":
            self._read_steering()
        self._decide_requests()
        if self._estop.is_set():
            self._estop.clear()
            if self.pilot.mode == "following":
                self.pilot.stop("estop")
                self.log.warning("estop: stopped")
        before = self.pilot.mode
        # armed before the angle is made: the pilot plans from the steering's target and limits
        if self.pilot.mode == "following" and self.client.lease is None and not self._arm():
            return
        angle_rad = self.pilot.tick(clock.time_ns())
        if angle_rad is None:
            if self.pilot.mode != before:
                self.log.info("%s: %s", self.pilot.mode, self.pilot.reason)
            self._give_back_lease()
            return
        self._setpoint(math.degrees(angle_rad))

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

    def _read_steering(self) -> None:
        """The newest steering state, if one came since the last tick; stamped with when it
        was read, at most one tick after it arrived."""
        sample = self._steering_states.try_recv()
        if sample is None:
            return
        try:
            armed, owner, trip, speed = _STEERING(unpack(sample.payload.to_bytes(), "steering state"))
        except InputError:
            self.health.error("bad_steering_state")
            return
        self._steering = (clock.monotonic(), armed, owner, trip)
        self.pilot.steering_speed_mps = speed

    def _arm(self) -> bool:
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
            self._give_back_lease()
            return False
        self._owner, self._armed_at = reply.get("owner"), clock.monotonic()
        self.health.count("armed")
        self.log.info("armed: following the route")
        return True

    def _setpoint(self, angle_deg: float) -> None:
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
            self._give_back_lease()

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
            self._give_back_lease()
            return
        self.client.put_setpoint(angle_deg)
        self.health.count("setpoint")
        # From the estimate's stamp to the setpoint made from it sent (or answered, for
        # queries). The stamp is the estimator's clock: on one machine, or machines kept in
        # sync, it is the whole way from the sensors' time to the steering.
        est = self.pilot.estimate
        assert est is not None, "a setpoint is made from an estimate"
        self._latencies.add((clock.time_ns() - est.t_ns) * 1e-9)

    def _give_back_lease(self) -> None:
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
        self.session.put(self.keys.key("steering", "estop"), b"{}")
        return False

    # -- requests, read by the inbox ----------------------------------------------------------------
    def _decide_requests(self) -> None:
        """Those read since the last tick (a query's answers end when this returns and its
        last reference goes: not after the arm that a start leads to)."""
        for request in self.inbox.take():
            try:
                self._handle(request)
            finally:
                self.inbox.decided()

    def _handle(self, request: Request) -> None:
        if request.kind == ROUTE:
            self._take_route(request)
        elif request.value == "start":
            self._start(request)
        else:
            self.pilot.stop("stop command")
            self._give_back_lease()
            request.answer({"status": ACCEPTED, "mode": self.pilot.mode})

    def _take_route(self, request: Request) -> None:
        route = request.value
        try:
            self.pilot.set_route(route)
        except RouteError as exc:
            self.inbox.refuse(request, str(exc))
            return
        self.health.count("route")
        self._path_due = 0.0                          # publish it now
        self.log.info("route: %d checkpoints, %.0f m (%s)", len(route), route.length_m, route.form)
        if self.pilot.mode == IDLE:
            request.answer_accepted()
        else:
            request.answer({"status": ACCEPTED, "route": route.to_geojson(), "mode": self.pilot.mode})

    def _start(self, request: Request) -> None:
        if request.number < self._estop_number:
            self.inbox.refuse(request, "an estop came after this start")
            return
        why = self.pilot.start(clock.time_ns())
        if why is not None:
            self.inbox.refuse(request, why)
            return
        self.log.info("start: following")
        request.answer({"status": ACCEPTED, "mode": self.pilot.mode})

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


class Window:
    """p50 and p99 of a delay over the last 500 times, set in health (ms) once per 500."""

    def __init__(self, health, name: str, size: int = 500):
        self._health, self._name, self._size = health, name, size
        self._values_s: list[float] = []

    def add(self, value_s: float) -> None:
        self._values_s.append(value_s)
        if len(self._values_s) >= self._size:
            ordered = sorted(self._values_s)
            self._health.set(self._name, {"p50": round(ordered[self._size // 2 - 1] * 1e3, 2),
                                          "p99": round(ordered[self._size * 99 // 100 - 1] * 1e3, 2)})
            self._values_s.clear()


def main(argv: list[str] | None = None) -> int:
    return run_service(PilotService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
