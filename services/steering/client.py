"""A small steering client: arm, hold an angle by streaming setpoints, disarm.

The watchdog (500 ms by default) gives up on a client that stops talking, so one `zenoh
get` typed by hand is too slow to keep the wheel; this keeps the stream going:

    python -m viena.services.steering.client --connect tcp/127.0.0.1:7447 --angle-deg 5 --seconds 10

Setpoints are signed with the lease, never sent with it (model/signing.py). For the `zenoh`
CLI, `--sign LEASE` prints one signed setpoint to put or get:

    zenoh put -k viena/elettra/steering/setpoint -v "$(viena-steer --sign "$LEASE" --angle-deg 5)"
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import weakref
from typing import Any

from viena.common import clock
from viena.common.keys import Keys
from viena.common.samples import topics
from viena.common.session import zenoh_options
from viena.services.steering.model.signing import signed_setpoint

#: the router lets one query per client and command key through in this long (the query
#: limits of compose/zenoh/router.json5, with a margin): a query sent sooner is dropped
#: there and never answered, so `ask` waits out the rest first. Counted from the last
#: answer, which the router saw after that query: a late query answered at once is then
#: still not followed within the limit by the next (it was, by a stream catching up, in CI)
QUERY_SPACING_S = {"setpoint": 1 / 150}
ONE_OFF_QUERY_SPACING_S = 1 / 15            # arm, calibration, estop: questions seconds apart


_seq_lock = threading.Lock()
#: clock -> the last seq given on it: the wall clock's for the process, each lockstep car
#: its own (two drives in one process then count alike)
_last_seq: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def next_seq() -> int:
    """A setpoint counter that grows on every call in this process and across processes run
    one after another (nanoseconds since 1970, bumped when two calls share one): a client or
    a one-off `viena-steer --sign` needs no state of its own to keep `seq` growing."""
    with _seq_lock:
        on = clock.current()
        seq = _last_seq[on] = max(clock.time_ns(), _last_seq.get(on, 0) + 1)
        return seq


class ConflictingReplies(RuntimeError):
    """More than one process answered a steering command, or not the one that granted the
    lease: something impersonates the steering service, and no answer can be trusted."""


def _session_of(reply) -> str:
    replier = reply.replier_id
    return str(replier.zid) if replier is not None else "unknown"


class SteeringClient:
    """The owner's side of the steering API on an open zenoh session.

    Every question goes to every queryable (zenoh's QueryTarget.ALL, no consolidation), so
    a second process answering the steering keys is seen rather than silently winning: the
    answers must come from exactly one replier, and once armed from the one that granted
    the lease. Anything else raises ConflictingReplies."""

    def __init__(self, session, car: str = "elettra", timeout_s: float = 2.0, name: str | None = None):
        self.session, self.car, self.timeout_s = session, car, timeout_s
        self.name = name                       # who this is, for the steering's log of e-stops
        self._asked: dict[str, float] = {}     # when each key was last asked (monotonic s)
        self.lease: str | None = None
        self.replier: str | None = None        # the steering service that granted the lease
        self.last_replier: str | None = None
        self._setpoint_pub: Any = None         # for put_setpoint, declared on first use (a zenoh Publisher)

    def ask(self, name: str, payload: dict, timeout_s: float | None = None) -> dict:
        """One command, answered by exactly one steering service; `timeout_s` for this one
        question (default: the client's)."""
        import zenoh

        self._space(name)
        replies = list(self.session.get(Keys(self.car).of(topics.BY_NAME[f"steering.{name}"]),
                                        payload=json.dumps(payload).encode(),
                                        timeout=self.timeout_s if timeout_s is None else timeout_s,
                                        target=zenoh.QueryTarget.ALL,
                                        consolidation=zenoh.ConsolidationMode.NONE))
        self._asked[name] = clock.monotonic()
        # the replying session (its zenoh id), not the queryable: one service has several
        answers = [(_session_of(r), r.ok) for r in replies if r.ok is not None]
        if not answers:
            return {"status": "rejected", "reason": f"no answer on {name}: is viena-steering running?"}
        repliers = sorted({replier for replier, _ in answers})
        if len(repliers) > 1:
            raise ConflictingReplies(f"{len(repliers)} processes answered steering/{name} "
                                     f"({', '.join(repliers)}): only the steering service may")
        if self.replier is not None and repliers[0] != self.replier:
            raise ConflictingReplies(f"steering/{name} was answered by {repliers[0]}, not by "
                                     f"{self.replier}, which granted the lease")
        self.last_replier = repliers[0]
        return json.loads(answers[0][1].payload.to_bytes())

    def _space(self, name: str) -> None:
        """Wait out what is left of the router's spacing since the last `name` (QUERY_SPACING_S)."""
        spacing = QUERY_SPACING_S.get(name, ONE_OFF_QUERY_SPACING_S)
        wait = self._asked.get(name, -math.inf) + spacing - clock.monotonic()
        if wait > 0:
            clock.sleep(wait)

    def arm(self) -> dict:
        reply = self.ask("arm", {"arm": True})
        self.lease = reply.get("lease")
        if self.lease:
            self.replier = self.last_replier
        return reply

    def signed(self, angle_deg: float) -> dict:
        """A setpoint signed with the lease (never carrying it): nobody who sees it can use it
        for an angle of their own, or send it again."""
        if self.lease is None:
            raise RuntimeError("not armed: arm() first, the lease signs every setpoint")
        return signed_setpoint(self.lease, angle_deg, seq=next_seq())

    def setpoint(self, angle_deg: float, timeout_s: float | None = None) -> dict:
        return self.ask("setpoint", self.signed(angle_deg), timeout_s)

    def put_setpoint(self, angle_deg: float) -> None:
        """A signed setpoint as a put: nothing comes back (the steering's state says whether
        it still steers for this lease), so a stream costs a fraction of `setpoint`'s."""
        import msgpack
        import zenoh

        if self._setpoint_pub is None:
            self._setpoint_pub = self.session.declare_publisher(Keys(self.car).of(topics.STEERING_SETPOINT))
        self._space("setpoint")                   # the router's limit holds for puts too
        self._setpoint_pub.put(msgpack.packb(self.signed(angle_deg)),
                               encoding=zenoh.Encoding("application/msgpack"))
        self._asked["setpoint"] = clock.monotonic()

    def close(self) -> None:
        """Undeclare what the client declared (the session stays open)."""
        if self._setpoint_pub is not None:
            self._setpoint_pub.undeclare()
            self._setpoint_pub = None

    def disarm(self) -> dict:
        reply = self.ask("arm", {"arm": False, "lease": self.lease})
        self.lease, self.replier = None, None
        return reply

    def estop(self) -> dict:
        return self.ask("estop", {"by": self.name} if self.name else {})

    def hold(self, angle_deg: float, seconds: float, rate_hz: float = 20.0) -> dict:
        """Stream one angle; returns the last reply (stops early on a rejection)."""
        reply: dict = {}
        end = clock.monotonic() + seconds
        while clock.monotonic() < end:
            reply = self.setpoint(angle_deg)
            if reply.get("status") == "rejected":
                break
            clock.sleep(1.0 / rate_hz)
        return reply


def _parser() -> argparse.ArgumentParser:
    from viena.common.session import add_common_arguments

    p = argparse.ArgumentParser(prog="viena-steer", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--angle-deg", type=float, required=True, help="wheel angle in degrees, positive left")
    p.add_argument("--sign", metavar="LEASE",
                   help="print one setpoint signed with LEASE (JSON, for `zenoh put`/`get`) and exit")
    p.add_argument("--stamp", action="store_true",
                   help="with --sign: stamp it with this machine's time (refused once 0.5 s old: "
                        "only where this clock agrees with the steering's)")
    p.add_argument("--seconds", type=float, default=5.0, help="how long to hold it (default 5)")
    p.add_argument("--rate-hz", type=float, default=20.0, help="setpoints per second (default 20)")
    p.add_argument("--timeout", type=float, default=10.0,
                   help="give up if the router cannot be reached in this many seconds (default 10)")
    add_common_arguments(p)
    return p


def main(argv=None) -> int:
    from viena.common.errors import InputError
    from viena.common.log import setup_logging
    from viena.common.session import Unreachable, car_name, load_settings_file, open_session, zenoh_config

    args = _parser().parse_args(argv)
    if args.sign is not None:
        print(json.dumps(signed_setpoint(args.sign, args.angle_deg, seq=next_seq(),
                                         t_ns=clock.time_ns() if args.stamp else None)))
        return 0
    setup_logging("WARNING" if args.log_level == "INFO" else args.log_level)
    try:
        toml = load_settings_file(args)
        car = car_name(args, toml)
        # a person at the wheel: their own identity ($VIENA_IDENTITY or --identity), else `pilot`
        identity = os.environ.get("VIENA_IDENTITY") or "pilot"
        conf = zenoh_config(args, toml, identity=identity)
        session = open_session(conf, timeout_s=args.timeout)
    except (InputError, Unreachable) as exc:
        print(f"viena-steer: {exc}", file=sys.stderr)
        return 2
    try:
        client = SteeringClient(session, car, name=identity)
        reply = client.arm()
        print(json.dumps(reply))
        if reply.get("status") != "accepted":
            return 1
        try:
            held = client.hold(args.angle_deg, args.seconds, args.rate_hz)
            print(json.dumps(held))
            if held.get("limits"):             # what the envelope made of the angle, for a person
                goal = held.get("goal_deg", held.get("target_deg"))
                print(f"viena-steer: limited to {goal:.2f} deg: {held.get('reason')}", file=sys.stderr)
        finally:
            print(json.dumps(client.disarm()))
    except ConflictingReplies as exc:
        print(f"viena-steer: stopped: {exc}", file=sys.stderr)
        session.put(Keys(car).of(topics.STEERING_ESTOP), json.dumps({"by": identity}).encode(),   # puts too
                    **zenoh_options(topics.STEERING_ESTOP))
        return 3
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
