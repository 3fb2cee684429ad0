"""Serve one GNSS twin on its own, without the whole simulated car.

    python -m viena.services.gnss.simulator --kind novatel --port 5001
    python -m viena.services.gnss.simulator --kind nmea --motion route
    python -m viena.services.gnss.simulator --replay drive --replay-speed 5
    python -m viena.services.gnss.simulator --com2-port 0 --model RT20

It prints ``READY <url>`` once the twin listens (the URL a driver opens), then
``COM2 <url>`` when the NovAtel's second port (for corrections) is served too, and runs
until SIGTERM or Ctrl-C. ``--motion parked`` keeps the car at the IST origin; ``route`` drives
the simulated car's default loop.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from viena.common.signals import stop_on_signals
from viena.common.twin.serial_port import SerialEndpoint
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import IST_ORIGIN, Truth

from .nmea_twin import NmeaTwin
from .novatel_twin import NovatelTwin
from .replay import DRIVE_CSV, load_drive

CAR_RATE_HZ = 100.0


def parked_truth(origin=IST_ORIGIN, t_ns: int = 0) -> Truth:
    """The car standing at ``origin``, facing north."""
    zero = np.zeros(3)
    return Truth(t_ns=t_ns, t_s=0.0, origin=tuple(origin), enu_m=zero.copy(),
                 vel_enu_mps=zero.copy(), accel_enu_mps2=zero.copy(),
                 quat=np.array([1.0, 0.0, 0.0, 0.0]), gyro_body_radps=zero.copy(),
                 speed_mps=0.0, wheel_angle_rad=0.0)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m viena.services.gnss.simulator",
                                description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kind", choices=("novatel", "nmea"), default="novatel")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0, help="TCP port (default: any free one)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lever-arm", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"), help="antenna in the body frame, m")
    p.add_argument("--outage-interval-s", type=float, default=64.0,
                   help="mean time between INSUFFICIENT_OBS periods (0: none)")
    p.add_argument("--motion", choices=("parked", "route"), default="parked")
    p.add_argument("--replay", metavar="CSV", help='a BESTXYZ recording; "drive" = the 2016 drive')
    p.add_argument("--rows", type=int, nargs=2, metavar=("START", "STOP"),
                   help="replay only rows [START, STOP) of the recording")
    p.add_argument("--replay-speed", type=float, default=1.0)
    p.add_argument("--replay-loop", action="store_true")
    p.add_argument("--replay-keep-time", action="store_true",
                   help="keep the recording's own GPS times instead of moving them to now")
    p.add_argument("--com2-port", type=int, default=-1,
                   help="NovAtel: also serve its COM2 (corrections) on this TCP port (0: any free one)")
    p.add_argument("--model", default="RT2WA", help="NovAtel: the model VERSION says (RT2..., RT20..., 3151R)")
    p.add_argument("--firmware", default="2.310", help="NovAtel: the firmware VERSION says")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    stop = stop_on_signals()
    truth, car = None, None
    replay = None
    if args.replay:
        path = DRIVE_CSV if args.replay == "drive" else args.replay
        start, end = args.rows if args.rows else (0, None)
        replay = load_drive(path, start, end)
    elif args.motion == "route":
        car = SimCar()
        truth = car.truth
    else:
        still = parked_truth()
        truth = lambda: still  # noqa: E731
    common = dict(seed=args.seed, lever_arm_m=args.lever_arm,
                  outage_interval_s=args.outage_interval_s, replay=replay,
                  replay_speed=args.replay_speed, replay_loop=args.replay_loop,
                  replay_retime=not args.replay_keep_time)
    twin: NovatelTwin | NmeaTwin
    if args.kind == "novatel":
        twin = NovatelTwin(truth, model=args.model, firmware=args.firmware, **common)
    else:
        twin = NmeaTwin(truth, **common)
    endpoint = SerialEndpoint(twin, args.host, args.port, name=args.kind).start()
    endpoints = [endpoint]
    print(f"READY {endpoint.url}", flush=True)
    if isinstance(twin, NovatelTwin) and args.com2_port >= 0:     # (kind novatel)
        com2 = SerialEndpoint(twin.port("COM2"), args.host, args.com2_port, name="novatel.com2").start()
        endpoints.append(com2)
        print(f"COM2 {com2.url}", flush=True)
    try:
        if car is not None:
            dt = 1.0 / CAR_RATE_HZ
            while not stop.wait(dt):
                car.step(dt)
        else:
            stop.wait()
    finally:
        for e in endpoints:
            e.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
