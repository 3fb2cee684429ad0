"""`viena`: run the car, watch it, and measure it.

    viena up [--profile sim] [-d]     start a profile under supervisor (Ctrl-C stops it)
    viena status | logs NAME | down   look after a running profile
    viena update                      apply edits of a running profile (a moved program)
    viena sub [KEYEXPR]               print samples, one per line
    viena router                      a zenoh router (for machines without zenohd)
    viena bench [NAME ...]            print the benchmark figures
    viena calibrate imu ...           fit IMU calibrations from recordings
    viena settings [SERVICE]          every setting of a service: type, default, meaning
"""
from __future__ import annotations

import argparse
import importlib
import sys

from viena import compose, router, sub

BENCHES = ["sim", "gnss", "imu", "steering", "estimator", "laptop", "security"]

#: commands that live in their own module, each with build_parser(parser) and run(args)
TOOLS = {
    "monitor": ("viena.monitor", "live dashboard of every service"),
    "record": ("viena.record", "record samples into an MCAP file"),
    "replay": ("viena.replay", "publish a recording back into the dataflow"),
    "export": ("viena.export", "an MCAP recording as CSV or JSON"),
    "plot": ("viena.plot", "a recorded drive as a PNG"),
    "keys": ("viena.keys", "the car's certificates: init, issue, list, zenoh-config"),
    "settings": ("viena.settings", "every setting of a service: type, default, meaning"),
}
CALIBRATIONS = {"imu": "viena.services.imu.calibration_cli"}


def _profile_arg(p: argparse.ArgumentParser, default: str | None = compose.DEFAULT_PROFILE) -> None:
    p.add_argument("--profile", default=default,
                   help=f"compose profile: {', '.join(compose.profiles())} (default {default or 'the running one'})")


def _running_profile(args) -> str:
    if args.profile:
        return args.profile
    running = compose.running_profiles()
    if len(running) == 1:
        return running[0]
    if not running:
        return compose.DEFAULT_PROFILE
    raise compose.ComposeError(f"several profiles are up ({', '.join(running)}): say --profile")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="viena", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    cmds = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = cmds.add_parser("up", help="start a profile under supervisor")
    _profile_arg(p)
    p.add_argument("-d", "--detach", action="store_true", help="run in the background")
    p.add_argument("--free-ports", action="store_true",
                   help="pick free ports for the profile's VIENA_*_PORT variables")
    p.add_argument("--secure", action="store_true",
                   help="TLS and access control, as on the car, whatever the profile's default "
                        "(needs `viena keys init`)")
    p.add_argument("--insecure", action="store_true",
                   help="plain TCP without access control, even where the router is reachable "
                        "from other machines (a trusted network only)")
    p.add_argument("--keys", metavar="DIR",
                   help="the car's key store (default $VIENA_KEYS, else ~/.config/viena/keys/CAR)")
    p.set_defaults(func=lambda a: compose.up(a.profile, a.detach, a.free_ports,
                                             a.secure, a.insecure, a.keys))

    p = cmds.add_parser("down", help="stop a running profile and everything in it")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.down(_running_profile(a)))

    p = cmds.add_parser("update", help="apply edits of a running profile's files")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.update(_running_profile(a)))

    p = cmds.add_parser("status", help="what runs in a profile")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.status(_running_profile(a)))

    p = cmds.add_parser("logs", help="a program's log")
    p.add_argument("program", help="program name in the profile (router, sim, gnss0, ...)")
    p.add_argument("-f", "--follow", action="store_true")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.logs(_running_profile(a), a.program, a.follow))

    p = cmds.add_parser("sub", help="print samples of a key expression")
    sub.build_parser(p)
    p.set_defaults(func=sub.run)

    p = cmds.add_parser("router", help="run a zenoh router")
    router.build_parser(p)
    p.set_defaults(func=router.run)

    for name, (module_name, help_text) in TOOLS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        p = cmds.add_parser(name, help=help_text, description=module.__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        module.build_parser(p)
        p.set_defaults(func=module.run)

    p = cmds.add_parser("bench", help="print benchmark figures")
    p.add_argument("names", nargs="*", metavar="NAME", help=f"any of {', '.join(BENCHES)} (default all)")
    p.set_defaults(func=_bench)

    p = cmds.add_parser("calibrate", help="fit a device calibration")
    p.add_argument("device", choices=sorted(CALIBRATIONS))
    p.add_argument("rest", nargs=argparse.REMAINDER, help="the calibration's own arguments")
    p.set_defaults(func=lambda a: importlib.import_module(CALIBRATIONS[a.device]).main(a.rest))
    return parser


def _bench(args) -> int:
    """Benchmarks are development tools: they live in the source checkout (benchmarks/),
    not in what the car installs."""
    status = 0
    for name in args.names or BENCHES:
        if name not in BENCHES:
            print(f"viena bench: unknown benchmark {name!r} (have {', '.join(BENCHES)})", file=sys.stderr)
            return 2
        try:
            module = importlib.import_module(f"benchmarks.{name}")
        except ModuleNotFoundError as exc:
            if exc.name not in ("benchmarks", f"benchmarks.{name}"):
                raise
            print("viena bench: the benchmarks come with the source checkout (benchmarks/); "
                  "install viena from it with `pip install -e .`", file=sys.stderr)
            return 2
        print(f"## {name}", flush=True)
        status |= module.main([]) or 0
    return status


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args) or 0
    except compose.ComposeError as exc:
        print(f"viena: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
