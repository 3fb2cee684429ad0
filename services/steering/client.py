"""A small steering client: arm, hold an angle by streaming setpoints, disarm.

The watchdog (500 ms by default) gives up on a client that stops talking, so one `zenoh
get` typed by hand is too slow to keep the wheel; this keeps the stream going:

    python -m viena.services.steering.client --connect tcp/127.0.0.1:7447 --angle-deg 5 --seconds 10
"""
from __future__ import annotations

import argparse
import json
import sys
import time

KEY = "viena/{car}/steering/{name}"


class SteeringClient:
    """The owner's side of the steering API on an open zenoh session."""

    def __init__(self, session, car: str = "elettra", timeout_s: float = 2.0):
        self.session, self.car, self.timeout_s = session, car, timeout_s
        self.lease: str | None = None

    def ask(self, name: str, payload: dict) -> dict:
        replies = list(self.session.get(KEY.format(car=self.car, name=name),
                                        payload=json.dumps(payload).encode(), timeout=self.timeout_s))
        if not replies or replies[0].ok is None:
            return {"status": "rejected", "reason": f"no answer on {name}: is viena-steering running?"}
        return json.loads(replies[0].ok.payload.to_bytes())

    def arm(self) -> dict:
        reply = self.ask("arm", {"arm": True})
        self.lease = reply.get("lease")
        return reply

    def setpoint(self, angle_deg: float) -> dict:
        return self.ask("setpoint", {"angle_deg": angle_deg, "lease": self.lease})

    def disarm(self) -> dict:
        reply = self.ask("arm", {"arm": False, "lease": self.lease})
        self.lease = None
        return reply

    def estop(self) -> dict:
        return self.ask("estop", {})

    def hold(self, angle_deg: float, seconds: float, rate_hz: float = 20.0) -> dict:
        """Stream one angle; returns the last reply (stops early on a rejection)."""
        reply: dict = {}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            reply = self.setpoint(angle_deg)
            if reply.get("status") == "rejected":
                break
            time.sleep(1.0 / rate_hz)
        return reply


def main(argv=None) -> int:
    import zenoh

    from viena.common.config import load_zenoh_config

    p = argparse.ArgumentParser(prog="viena-steer", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", metavar="ENDPOINT")
    p.add_argument("--car", default="elettra")
    p.add_argument("--angle-deg", type=float, required=True, help="wheel angle, positive left")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--rate-hz", type=float, default=20.0)
    args = p.parse_args(argv)
    session = zenoh.open(load_zenoh_config(mode="client", connect=[args.connect]))
    try:
        client = SteeringClient(session, args.car)
        reply = client.arm()
        print(json.dumps(reply))
        if reply.get("status") != "accepted":
            return 1
        try:
            print(json.dumps(client.hold(args.angle_deg, args.seconds, args.rate_hz)))
        finally:
            print(json.dumps(client.disarm()))
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
