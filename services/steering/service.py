"""`viena-steering`: the steering wheel on zenoh (docs/steering.md; README.md in this folder).

    viena/<car>/steering/arm          query  {"arm": true} -> {"status", "lease", ...}
                                             {"arm": false, "lease": L}
    viena/<car>/steering/setpoint     query or put  {"angle_deg": x, "seq": n, "t": ns, "mac": M}
                                             (or angle_rad), signed with the lease (model/signing.py)
                                             -> {"status": accepted|clamped|rejected, "reason",
                                                 "target_deg", "angle_deg", "limits"}
    viena/<car>/steering/estop        query or put, any payload: quick stop, disarm
    viena/<car>/steering/calibration  query  {} status, {"restart": true}, {"finish": true}
    viena/<car>/steering/state        published at state_rate_hz (default 50)

Payloads are msgpack maps or JSON text; a reply comes back in the query's encoding. The
zenoh callbacks decode the payload and hand it to the controller, which decides at once in
the callback's thread (microseconds, a frame or two on the bus; nothing queues); an arm is
answered once the drive is enabled.

A command acts only when it was meant: a query whose key expression is exactly the
command's key, with a payload that parses as a map (bounded in size and depth before
parsing). A wildcard query (`zenoh get 'viena/**'`) gets a description of the command and
nothing happens; an empty or malformed payload gets the reason. An e-stop is `{}` (or any
map) on steering/estop, by put or query.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import zenoh

from viena.common.errors import InputError, PayloadError
from viena.common.log import Throttled
from viena.common.payload import parse_payload
from viena.common.samples import topics
from viena.common.samples.estimator import STATE as ESTIMATOR_STATE
from viena.common.samples.fix import FIX
from viena.common.schema import unpack
from viena.common.service import Service, query_payload, reply_to, run_service
from viena.common.settings import part
from viena.services.steering.controller import ControllerSettings, SteeringController
from viena.services.steering.driver import DriveSettings, EposDrive
from viena.services.steering.model.calibration import CalibrationSettings
from viena.services.steering.model.lateral import LateralSettings
from viena.services.steering.model.safety import REJECTED, Envelope, SafetySettings
from viena.services.steering.model.speed import SpeedSettings


@dataclass(frozen=True)
class SteeringSettings:
    """[steering]: the drive on its CAN bus, its calibration, the envelope, the controller.
    Each part is the model's own settings; the TOML table and the flags name them flat."""
    drive: DriveSettings = part(DriveSettings, "the CAN link and the drive's configuration")
    calibration: CalibrationSettings = part(CalibrationSettings, "the power-up lock-to-lock sweep")
    envelope: SafetySettings = part(SafetySettings, "what a setpoint may do")
    lateral: LateralSettings = part(LateralSettings, "how far and fast the wheel may turn at a speed")
    speed: SpeedSettings = part(SpeedSettings, "where the envelope's speed comes from")
    controller: ControllerSettings = part(ControllerSettings, "stops, state, reconnects")


class SteeringService(Service):
    """The EPOS 70/10 steering drive: arm, setpoints inside the safety envelope, watchdog."""

    name = "steering"
    settings_class = SteeringSettings
    default_unit = None

    def __init__(self, args):
        super().__init__(args)
        self._refusals = Throttled(self.log, "refused")

    def start(self) -> None:
        s = self.settings
        if self.log.getEffectiveLevel() > logging.DEBUG:
            logging.getLogger("canopen").setLevel(logging.WARNING)   # one line per PDO otherwise
        drive = EposDrive(s.drive)
        self._state_pub = self.publisher(topics.STEERING_STATE)
        envelope = Envelope(s.envelope, s.lateral, s.speed)
        self.controller = SteeringController(drive, envelope, s.calibration, s.controller, on_state=self._publish_state)
        for topic in (topics.STEERING_ARM, topics.STEERING_SETPOINT, topics.STEERING_CALIBRATION):
            name = topic.name.removeprefix("steering.")
            self.declare_queryable(self.keys.of(topic), self._command(name, self.keys.of(topic)))
        self.declare_queryable(self.keys.of(topics.STEERING_ESTOP), self._estop_query)
        self.declare_subscriber(self.keys.of(topics.STEERING_SETPOINT), self._setpoint_put)
        self.declare_subscriber(self.keys.of(topics.STEERING_ESTOP), self._estop_put)
        # the car's speed, for the envelope (model/speed.py): whom the router lets publish these
        self.declare_subscriber(self.keys.of(topics.ESTIMATOR_STATE), self._speed_input(speed_of_state))
        self.declare_subscriber(self.keys.of(topics.GNSS_FIX), self._speed_input(speed_of_fix))
        self.controller.start()

    def stop(self) -> None:
        if hasattr(self, "controller"):
            self.controller.stop()

    # -- zenoh callbacks: decode, decide, never wait ----------------------------------------
    def _command(self, kind: str, own_key: str):
        def on_query(query: zenoh.Query) -> None:
            data, encoding = query_payload(query)
            if str(query.key_expr) != own_key:
                self.health.count("discovery_queries")
                reply_to(query, describe(kind, own_key), encoding, data, own_key)
                return
            self.health.count(kind)
            payload = self._parse(kind, data, encoding, query)
            if payload is not None:
                self.controller.submit(kind, payload, lambda answer: reply_to(query, answer, encoding, data))
        return on_query

    def _parse(self, kind: str, data: bytes, encoding: str | None, query=None) -> dict | None:
        """The command's map, or None after saying why (to the asker, if it asked)."""
        if kind == "calibration" and not data:
            return {}                                 # an empty question: the status
        try:
            return parse_payload(data, encoding)
        except PayloadError as exc:
            self.health.error("bad_payload")
            self._refusals.log(f"{kind}: {str(exc).split(':')[0]}", str(exc))
            if query is not None:
                reply_to(query, {"status": REJECTED, "reason": str(exc)}, encoding, data)
            return None

    def _setpoint_put(self, sample: zenoh.Sample) -> None:
        self.health.count("setpoint")
        payload = self._parse("setpoint", sample.payload.to_bytes(), str(sample.encoding))
        if payload is not None:
            self.controller.submit("setpoint", payload, None)

    def _estop_query(self, query: zenoh.Query) -> None:
        data, encoding = query_payload(query)
        own = self.keys.of(topics.STEERING_ESTOP)
        if str(query.key_expr) != own:
            self.health.count("discovery_queries")
            reply_to(query, describe("estop", own), encoding, data, own)
            return
        payload = self._parse("estop", data, encoding, query)
        if payload is not None:
            reply_to(query, self.controller.estop(payload), encoding, data)

    def _estop_put(self, sample: zenoh.Sample) -> None:
        payload = self._parse("estop", sample.payload.to_bytes(), str(sample.encoding))
        if payload is not None:
            self.controller.estop(payload)

    def _speed_input(self, read):
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                source, t_ns, speed, sigma, valid = read(unpack(sample.payload.to_bytes(), "speed input"))
            except InputError as exc:
                self.health.error("speed_input_malformed")
                self._refusals.log("speed input", f"a speed input not used: {exc}")
                return
            why = self.controller.speed(source, t_ns, speed, sigma, valid)
            if why:
                self.health.error(f"speed_refused_{why}")
                if why != "not_valid":
                    self._refusals.log(f"speed {why}", f"{source}'s speed refused ({why}): {speed!r} m/s")
        return on_sample

    def _publish_state(self, state: dict) -> None:
        if self._state_pub.put(state):
            self.health.count("state")
            self.health.mark_sample()
        self.health.set("phase", state["phase"])
        self.health.set("armed", state["armed"])
        self.health.set("setpoints_refused", dict(self.controller.envelope.refused))


COMMANDS = {
    "arm": ('{"arm": true} -> a lease; {"arm": false, "lease": L} to disarm', "pilot"),
    "setpoint": ('{"angle_deg": x, "seq": n, "t": ns, "mac": M} signed with the lease (never the lease '
                 'itself; `viena-steer --sign L --angle-deg x` makes one), as a query or a put', "pilot"),
    "calibration": ('{} for the status, {"restart": true} (disarmed), {"finish": true}', "pilot"),
    "estop": ('{} (any map; {"by": NAME} names you in the log), as a put or a query: quick stop now, disarm',
              "pilot or observer"),
}


def describe(kind: str, key: str) -> dict:
    """What a wildcard query gets instead of an action: how to use the command."""
    usage, who = COMMANDS[kind]
    return {"status": "description", "key": key, "usage": usage, "who": who,
            "note": "nothing was done: commands act only on a query of this exact key"}


_ESTIMATE = ESTIMATOR_STATE.reader("t", "position_valid", "speed_mps", "vel_var_m2ps2")
_FIX = FIX.reader("t", "unit", "valid", "vel_ecef_mps", "vel_sigma_mps", "lat_deg", "lon_deg")


def speed_of_state(state: dict) -> tuple[str, int, float, float, bool]:
    """(source, stamp, horizontal speed, its sigma, valid) from an estimator state."""
    t, valid, speed, var = _ESTIMATE(state)
    return "estimator", t, speed, math.sqrt(max(var[0], var[1], 0.0)), valid


def speed_of_fix(fix: dict) -> tuple[str, int, float, float, bool]:
    """(unit, stamp, horizontal speed, its sigma, valid) from a GNSS fix: the velocity
    without its vertical part; its largest sigma."""
    t, unit, valid, vel, sigma, lat, lon = _FIX(fix)
    if vel is None or sigma is None:
        return unit, t, math.nan, math.nan, False
    return unit, t, horizontal_speed(vel, lat, lon), max(sigma), valid


def horizontal_speed(vel_ecef: tuple[float, float, float], lat_deg: float, lon_deg: float) -> float:
    """The speed along the ground: the ECEF velocity's east and north (the local frame at
    the geodetic lat, lon, as pymap3d's uvw2enu turns it; checked against it in the
    tests). Written out because pymap3d brings numpy, 13 MB of the steering's memory, for
    these two lines."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    vx, vy, vz = vel_ecef
    east = -math.sin(lon) * vx + math.cos(lon) * vy
    north = -math.sin(lat) * (math.cos(lon) * vx + math.sin(lon) * vy) + math.cos(lat) * vz
    return math.hypot(east, north)


def main(argv=None) -> int:
    return run_service(SteeringService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
