"""`viena-steering`: the steering wheel on zenoh (design §8; README.md in this folder).

    viena/<car>/steering/arm          query  {"arm": true} -> {"status", "lease", ...}
                                             {"arm": false, "lease": L}
    viena/<car>/steering/setpoint     query or put  {"angle_deg": x, "lease": L} (or angle_rad)
                                             -> {"status": accepted|clamped|rejected, "reason",
                                                 "target_deg", "angle_deg", "limits"}
    viena/<car>/steering/estop        query or put, any payload: quick stop, disarm
    viena/<car>/steering/calibration  query  {} status, {"restart": true}, {"finish": true}
    viena/<car>/steering/state        published at state_rate_hz (default 50)

Payloads are msgpack maps or JSON text; a reply comes back in the query's encoding. The
zenoh callbacks decode the payload and hand it to the controller, which decides at once in
the callback's thread (microseconds, a frame or two on the bus; nothing queues); an arm is
answered once the drive is enabled.
"""
from __future__ import annotations

import logging

import zenoh

from viena.common.errors import PayloadError
from viena.common.payload import parse_payload, reply_bytes
from viena.common.service import Service, run_service
from viena.services.steering.model.calibration import CalibrationSettings
from viena.services.steering.controller import ControllerSettings, SteeringController
from viena.services.steering.driver import DriveSettings, EposDrive
from viena.services.steering.model.safety import REJECTED, Envelope, SafetySettings
from viena.services.steering.model.state import STATE


class SteeringService(Service):
    """The EPOS 70/10 steering drive: arm, setpoints inside the safety envelope, watchdog."""

    name = "steering"
    settings_defaults = {
        # the CAN link and the drive
        "interface": "socketcan",
        "channel": "can0",
        "bitrate": 1_000_000,
        "can_options": {},                 # extra python-can arguments
        "node_id": 1,
        "host_node_id": 100,
        "sync_period_s": 0.01,
        "drive_heartbeat_period_s": 0.1,
        "drive_heartbeat_timeout_s": 0.35,
        "host_heartbeat_period_s": 0.05,
        "host_heartbeat_timeout_s": 0.25,
        "encoder_pulses": 3600,
        "sensor_type": 2,
        "sensor_polarity": 0,
        "max_following_error_qc": 7500,
        # calibration
        "slope_deg_per_qc": -7.5014e-4,
        "limit_deg": 29.0,
        "min_span_qc": 90_000,
        "max_span_qc": 100_000,
        "sweep_settle_s": 0.5,             # the wheel still in the middle this long ends a sweep
        # the safety envelope
        "margin_deg": 1.0,
        "slew_deg_s": 30.0,
        "max_distance_deg": 4.0,
        "watchdog_s": 0.5,
        "max_age_s": 0.5,
        "quickstop_hold_s": 0.1,
        "state_rate_hz": 50.0,
    }
    default_unit = None

    @classmethod
    def add_arguments(cls, parser):
        parser.add_argument("--interface", dest="interface", metavar="NAME",
                            help="python-can interface (default socketcan; slcan for a serial adapter)")
        parser.add_argument("--channel", dest="channel", metavar="CHANNEL",
                            help="CAN channel (default can0; e.g. socket://127.0.0.1:PORT for slcan)")
        parser.add_argument("--node-id", dest="node_id", type=int, help="the drive's node id (default 1)")

    def start(self) -> None:
        s = self.settings
        if self.log.getEffectiveLevel() > logging.DEBUG:
            logging.getLogger("canopen").setLevel(logging.WARNING)   # one line per PDO otherwise
        options = dict(s["can_options"])
        if s["interface"] == "slcan" and str(s["channel"]).startswith("socket://"):
            options.setdefault("sleep_after_open", 0)     # no adapter to reset on a socket
            options.setdefault("timeout", 0.01)           # idle polling: 100/s, not 1000/s
        drive = EposDrive(DriveSettings(
            interface=s["interface"], channel=s["channel"], bitrate=s["bitrate"],
            node_id=s["node_id"], host_node_id=s["host_node_id"], sync_period_s=s["sync_period_s"],
            drive_heartbeat_period_s=s["drive_heartbeat_period_s"],
            drive_heartbeat_timeout_s=s["drive_heartbeat_timeout_s"],
            host_heartbeat_period_s=s["host_heartbeat_period_s"],
            host_heartbeat_timeout_s=s["host_heartbeat_timeout_s"],
            encoder_pulses=s["encoder_pulses"], sensor_type=s["sensor_type"],
            sensor_polarity=s["sensor_polarity"], max_following_error_qc=s["max_following_error_qc"],
            bus_options=options))
        envelope = Envelope(SafetySettings(
            margin_deg=s["margin_deg"], slew_deg_s=s["slew_deg_s"],
            max_distance_deg=s["max_distance_deg"], watchdog_s=s["watchdog_s"], max_age_s=s["max_age_s"]))
        calibration = CalibrationSettings(
            slope_deg_per_qc=s["slope_deg_per_qc"], limit_deg=s["limit_deg"],
            min_span_qc=s["min_span_qc"], max_span_qc=s["max_span_qc"], settle_s=s["sweep_settle_s"])
        self._state_pub = self.publisher(self.keys.key("steering", "state"), STATE)
        self.controller = SteeringController(
            drive, envelope, calibration,
            ControllerSettings(quickstop_hold_s=s["quickstop_hold_s"],
                               state_period_s=1.0 / s["state_rate_hz"]),
            on_state=self._publish_state)
        key = lambda name: self.keys.key("steering", name)        # noqa: E731
        for name in ("arm", "setpoint", "calibration"):
            self.declare_queryable(key(name), self._queued(name))
        self.declare_queryable(key("estop"), self._estop_query)
        self.declare_subscriber(key("setpoint"), self._setpoint_put)
        self.declare_subscriber(key("estop"), self._estop_put)
        self.controller.start()

    def stop(self) -> None:
        if hasattr(self, "controller"):
            self.controller.stop()

    # -- zenoh callbacks: decode, decide, never wait ----------------------------------------
    def _queued(self, kind: str):
        def on_query(query: zenoh.Query) -> None:
            data, encoding = _payload_of(query)
            self.health.count(kind)
            try:
                payload = parse_payload(data, encoding) if (data or kind != "calibration") else {}
            except PayloadError as exc:
                self.health.error("bad_payload")
                self.log.warning("%s query rejected: %s", kind, exc)
                _reply(query, {"status": REJECTED, "reason": str(exc)}, encoding, data)
                return
            self.controller.submit(kind, payload, lambda answer: _reply(query, answer, encoding, data))
        return on_query

    def _setpoint_put(self, sample: zenoh.Sample) -> None:
        self.health.count("setpoint")
        try:
            payload = parse_payload(sample.payload.to_bytes(), str(sample.encoding))
        except PayloadError as exc:
            self.health.error("bad_payload")
            self.log.warning("setpoint put rejected: %s", exc)
            return
        self.controller.submit("setpoint", payload, None)

    def _estop_query(self, query: zenoh.Query) -> None:
        data, encoding = _payload_of(query)
        _reply(query, self.controller.estop(), encoding, data)

    def _estop_put(self, sample: zenoh.Sample) -> None:
        self.controller.estop()

    def _publish_state(self, state: dict) -> None:
        if self._state_pub.put(state):
            self.health.count("state")
            self.health.mark_sample()
        self.health.set("phase", state["phase"])
        self.health.set("armed", state["armed"])


def _payload_of(query: zenoh.Query) -> tuple[bytes, str | None]:
    data = query.payload.to_bytes() if query.payload is not None else b""
    encoding = str(query.encoding) if query.encoding is not None else None
    return data, encoding


def _reply(query: zenoh.Query, answer: dict, encoding: str | None, data: bytes) -> None:
    payload, reply_encoding = reply_bytes(answer, encoding, data)
    query.reply(query.key_expr, payload, encoding=zenoh.Encoding(reply_encoding))


def main(argv=None) -> int:
    return run_service(SteeringService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
