"""`viena`: run the car, watch it, and measure it.

    viena up [--profile sim] [-d]     start a profile under supervisor (Ctrl-C stops it)
    viena status | down | update      look after a running profile
    viena logs | restart | stop | start NAME     one program of it
    viena doctor [--profile pi]       is this machine ready to run the profile?
    viena service install --profile pi    start the profile at boot (systemd)
    viena list | hz KEY | sub KEY     what the car publishes, how fast, and what
    viena monitor | record | replay   watch, record and play back the car
    viena info | export | plot FILE   look into a recording
    viena foxglove                    the car live in Foxglove (ws://localhost:8765)
    viena sim run [SCENARIO]          a closed-loop drive in virtual time (--seeds A..B: a table)
    viena route send|show|record      the route the pilot follows
    viena pilot start|stop|status     the pilot (viena-pilot) that steers along it
    viena keys ...                    the car's certificates
    viena router                      a zenoh router (for machines without zenohd)
    viena settings [SERVICE]          every setting of a service: type, default, meaning
    viena calibrate imu ...           fit IMU calibrations from recordings
    viena bench [NAME ...]            print the benchmark figures (source checkout only)

Every command takes --help and --version. A tool is a module with `build_parser(parser)`
and `run(args)`, named in TOOLS; adding one is one line there.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from viena import compose
from viena.common.session import add_version_flag

BENCHES = ["sim", "gnss", "imu", "steering", "steering_envelope", "estimator", "laptop", "security", "faults", "fleet",
           "foxglove", "pilot", "lockstep", "ntrip", "rtk", "blackbox", "pi"]

#: commands that live in their own module, each with build_parser(parser) and run(args);
#: a module that is not there (a tool not written yet) is left out of the command list
TOOLS = {
    "doctor": ("viena.doctor", "check that this machine is ready to run a profile"),
    "service": ("viena.boot", "start a profile at boot: a systemd unit"),
    "list": ("viena.discover", "the keys the car publishes, with schema and rate"),
    "hz": ("viena.hz", "rate, jitter and bandwidth of a key"),
    "sub": ("viena.sub", "print samples of a key expression"),
    "monitor": ("viena.monitor", "live dashboard of every service"),
    "record": ("viena.record", "record samples into an MCAP file"),
    "replay": ("viena.replay", "publish a recording back into the dataflow"),
    "info": ("viena.info", "what a recording holds: duration, keys, counts, rates"),
    "export": ("viena.export", "an MCAP recording as CSV, JSON or a file Foxglove opens"),
    "plot": ("viena.plot", "a recorded drive as a PNG"),
    "foxglove": ("viena.foxglove", "the car live in Foxglove or Lichtblick (WebSocket server)"),
    "keys": ("viena.keys_cli", "the car's certificates: init, issue, list, zenoh-config"),
    "ntrip": ("viena.ntrip_cli", "NTRIP casters: a caster's source table, nearest mountpoints first"),
    "router": ("viena.router", "run a zenoh router"),
    "settings": ("viena.settings_cli", "every setting of a service: type, default, meaning"),
    "sim": ("viena.sim_run", "closed-loop drives in virtual time: scenarios, a Monte-Carlo table"),
}
#: `viena TOOL SUB ...` run by a module of its own: the tool's own arguments are free words
#: (`viena record [KEYEXPR ...]`), so its parser cannot tell a subcommand from them
SUBTOOLS = {("record", "list"): ("viena.record_list", "the drives the black box recorded: span, distance, size")}
#: one program of a profile: `viena ACTION NAME`
PROGRAM_ACTIONS = {
    "logs": "a program's log (-f: follow it)",
    "restart": "stop and start one program, and check that it stays up",
    "stop": "stop one program (the rest keeps running)",
    "start": "start a stopped program, and check that it stays up",
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


def _add_profile_commands(cmds) -> None:
    p = cmds.add_parser("up", help="start a profile under supervisor")
    _profile_arg(p)
    p.add_argument("-d", "--detach", action="store_true",
                   help="run in the background; return once every program has stayed up (exit "
                        "status 1, with their logs' last lines, if any did not)")
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
    p.add_argument("--rtk", action="store_true",
                   help="with the corrections chain: the NTRIP client (viena-ntrip) and, in the sim, the "
                        "caster's twin; the receivers take its RTCM 3 (docs/sensors.md#corrections)")
    p.add_argument("--record", action="store_true",
                   help="with the black box (viena-recorder: every key into a drive of split files, "
                        "services/recorder/README.md); the pi profile runs it always")
    p.set_defaults(func=lambda a: compose.up(a.profile, a.detach, a.free_ports,
                                             a.secure, a.insecure, a.keys, a.rtk, a.record))

    p = cmds.add_parser("down", help="stop a running profile and everything in it")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.down(_running_profile(a)))

    p = cmds.add_parser("update", help="apply edits of a running profile's files")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.update(_running_profile(a)))

    p = cmds.add_parser("status", help="what runs in a profile")
    _profile_arg(p, None)
    p.set_defaults(func=lambda a: compose.status(_running_profile(a)))

    for action, help_text in PROGRAM_ACTIONS.items():
        p = cmds.add_parser(action, help=help_text)
        p.add_argument("program", metavar="NAME", help="program name in the profile (router, sim, gnss0, ...)")
        if action == "logs":
            p.add_argument("-f", "--follow", action="store_true", help="keep printing what it writes")
        _profile_arg(p, None)
        p.set_defaults(func=lambda a, action=action: compose.one_program(
            action, _running_profile(a), a.program, getattr(a, "follow", False)))


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; given the `command` about to run, only that tool's module is
    imported (the others show in the command list but stay unloaded): `viena status` on
    the Pi should not wait for the estimator, numpy and Foxglove to load."""
    parser = argparse.ArgumentParser(prog="viena", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_flag(parser)
    cmds = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_profile_commands(cmds)

    for name, (module_name, help_text) in TOOLS.items():
        if command is not None and name != command:
            cmds.add_parser(name, help=help_text)          # listed, not loaded
            continue
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
        p.epilog = "\n".join(f"viena {name} {sub} --help: {text}" for (tool, sub), (_, text) in SUBTOOLS.items()
                              if tool == name) or None
    from viena import pilot_cli  # two commands with subcommands: route, pilot
    pilot_cli.add_commands(cmds)

    p = cmds.add_parser("bench", help="print benchmark figures")
    p.add_argument("names", nargs=argparse.REMAINDER, metavar="NAME ...",
                   help=f"any of {', '.join(BENCHES)} (default all); one NAME may be followed by its own "
                        f"flags (`viena bench pi --seconds 60`; `viena bench pi --help` lists them)")
    p.set_defaults(func=_bench)

    p = cmds.add_parser("calibrate", help="fit a device calibration")
    p.add_argument("device", choices=sorted(CALIBRATIONS))
    p.add_argument("rest", nargs=argparse.REMAINDER, help="the calibration's own arguments")
    p.set_defaults(func=lambda a: importlib.import_module(CALIBRATIONS[a.device]).main(a.rest))

    for sub in cmds.choices.values():               # --version on every command
        if "--version" not in sub._option_string_actions:
            add_version_flag(sub)
    return parser


def _bench(args) -> int:
    """Benchmarks are development tools: they live in the source checkout (benchmarks/),
    not in what the car installs."""
    names, flags = list(args.names), []
    if len(names) > 1 and names[1].startswith("-"):          # one benchmark, with its own flags
        names, flags = names[:1], names[1:]
    status = 0
    for name in names or BENCHES:
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
        if len(names or BENCHES) > 1:                        # (one alone: its output is its own, --json too)
            print(f"## {name}", flush=True)
        status |= module.main(flags) or 0
    return status


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), "")   # "" for `viena --help`
    at = argv.index(command) if command else 0
    subtool = SUBTOOLS.get((command, argv[at + 1] if at + 1 < len(argv) else ""))
    if subtool is not None:
        return importlib.import_module(subtool[0]).main(argv[at + 2:])
    args = build_parser(command).parse_args(argv)
    try:
        return args.func(args) or 0
    except compose.ComposeError as exc:
        print(f"viena: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
