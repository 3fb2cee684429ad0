"""`viena doctor [--profile pi]`: is this machine ready to run the profile, and if not, what
to do. One line per check, OK, WARN or FAIL with the fix; the exit status is 1 if any
check failed (a WARN does not fail).

    versions   viena, zenoh, Python; a 32-bit ARM system is refused (no wheels)
    devices    each serial port a program of the profile opens: present, readable and
               writable by this user (a socket:// twin: listening); `/dev/ttyUSB*` names
               are a WARN, they change between boots
    can        the steering's CAN interface: present, up, at the configured bitrate
    keys       on a TLS profile: a valid certificate for every program (and the router)
    router     a zenoh session with the router the profile's clients use
    programs   when the profile is up: every program RUNNING
    clock      synchronised (timedatectl, else chronyc), and the host's offset from GNSS
               time in live fixes (`t_host` against `t` of viena.gnss.fix/1)
    disk       free space where recordings go (--recordings) and where logs go

The profile's settings are read as its programs read them (the service's settings
dataclass, the profile's TOML, the variables `viena up` saved or would set), so a
device moved by VIENA_GNSS0_DEVICE is checked where it now is.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import socket
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from viena import compose
from viena.common.errors import ConfigError, InputError
from viena.common.session import Unreachable, open_session, version_text, zenoh_config
from viena.runstate import run_dir

OK, WARN, FAIL = "OK", "WARN", "FAIL"
DISK_FAIL_BYTES = 1e9
DISK_WARN_BYTES = 5e9
ROUTER_TIMEOUT_S = 3.0
FIX_WAIT_S = 3.0
OFFSET_WARN_S = 0.2                 # above the serial link's own latency
OFFSET_FAIL_S = 1.0
_PROGRAM_COMMAND = re.compile(r"^\[program:([^\]]+)\]\s*\ncommand\s*=\s*(.+)$", re.M)
_SERVICE = re.compile(r"viena\.services\.(\w+)\.service\b(?:.*?--unit\s+(\S+))?")


@dataclass(frozen=True)
class Check:
    status: str
    name: str
    detail: str

    def line(self) -> str:
        return f"{self.status:<5} {self.name}: {self.detail}"


# -- the profile, as its programs see it --------------------------------------------------------
@dataclass(frozen=True)
class Program:
    name: str                   # supervisord's: gnss0, steering, router
    service: str | None         # gnss, imu, steering, ... (None: the router)
    unit: str | None


def profile_programs(conf: Path) -> list[Program]:
    from viena.profile_security import profile_text

    found = []
    for name, command in _PROGRAM_COMMAND.findall(profile_text(conf)):
        m = _SERVICE.search(command)
        found.append(Program(name, m.group(1) if m else None, m.group(2) if m else None))
    return found


def profile_environment(profile: str) -> tuple[dict[str, str], bool]:
    """The variables of the profile (saved by `viena up` if it runs, else as it would set
    them), and whether it is up."""
    up = compose.supervisord_pid(profile) is not None
    env = compose.read_environment(profile) if up else None
    return env or compose.environment(profile), up


def program_settings(program: Program, toml: dict, settings_path: str):
    """The settings the program runs with, read by its own service class."""
    from viena.settings import services

    cls = services()[program.service]
    unit = program.unit or cls.default_unit
    return cls.read_settings(toml, unit, argparse.Namespace(config=settings_path))


# -- checks -------------------------------------------------------------------------------------
def check_versions() -> list[Check]:
    machine = platform.machine()
    if machine in ("armv6l", "armv7l", "armhf", "i686"):
        return [Check(FAIL, "versions", f"{version_text()}: a 32-bit system; numpy, msgpack and "
                      f"zstandard have no wheels for it: install 64-bit Raspberry Pi OS (Bookworm)")]
    return [Check(OK, "versions", version_text())]


def check_serial(name: str, url: str) -> Check:
    what = f"{name} {url}"
    if not url:
        return Check(FAIL, what, "no port set: give it in the profile's settings")
    if url.startswith(("socket://", "rfc2217://")):
        host, _, port = url.split("://", 1)[1].split("/")[0].rpartition(":")
        return _listening(what, host, port, "the simulator (or the serial server) is not up?")
    path = Path(url)
    if not path.exists():
        return Check(FAIL, what, "no such device: plug it in; `ls -l /dev/serial/by-id/` lists what "
                     "is there; point the profile at it (docs/deployment.md, serial devices)")
    if not os.access(path, os.R_OK | os.W_OK):
        user = os.environ.get("USER") or "$USER"
        return Check(FAIL, what, f"not readable and writable by this user: `sudo usermod -aG dialout "
                     f"{user}`, then log in again")
    shown = f"-> {path.resolve()}" if path.is_symlink() else "present, readable"
    if re.fullmatch(r"/dev/tty(USB|ACM)\d+", url):
        return Check(WARN, what, f"{shown}, but /dev/ttyUSB numbers change between boots: use its "
                     f"/dev/serial/by-id/ name or a udev rule (docs/deployment.md)")
    return Check(OK, what, shown)


def _listening(what: str, host: str, port: str, hint: str) -> Check:
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=1.0):
            return Check(OK, what, "listening")
    except (OSError, ValueError) as exc:
        return Check(FAIL, what, f"nothing answers ({exc.strerror or exc}): {hint}")


def check_can(interface: str, channel: str, bitrate: int, ip_json: str | None = None) -> Check:
    """The steering's bus. `ip_json`: `ip -details -json link show CHANNEL` (read if None)."""
    what = f"can {interface} {channel}"
    if interface == "virtual":
        return Check(OK, what, "a virtual bus inside one process (no hardware)")
    if interface == "slcan":
        if channel.startswith("socket://"):
            host, _, port = channel.split("://", 1)[1].rpartition(":")
            return _listening(what, host, port, "the simulator's CAN adapter twin is not up?")
        return check_serial("can slcan", channel)
    if interface != "socketcan":
        return Check(WARN, what, "not checked (only socketcan, slcan and virtual are)")
    if ip_json is None:
        if shutil.which("ip") is None:
            return Check(WARN, what, "not checked: no `ip` command (iproute2)")
        done = subprocess.run(["ip", "-details", "-json", "link", "show", channel],
                              capture_output=True, text=True)
        if done.returncode != 0:
            return Check(FAIL, what, f"no interface {channel}: is the CAN HAT's overlay in "
                         f"/boot/firmware/config.txt, and the HAT seated? (docs/deployment.md, CAN)")
        ip_json = done.stdout
    return can_state(what, channel, bitrate, ip_json)


def can_state(what: str, channel: str, bitrate: int, ip_json: str) -> Check:
    """The verdict on one CAN interface from `ip -details -json link show` output."""
    try:
        link = json.loads(ip_json)[0]
    except (ValueError, IndexError, KeyError):
        return Check(WARN, what, "not checked: `ip` said something unexpected")
    info = link.get("linkinfo", {})
    data = info.get("info_data", {})
    up_cmd = f"`sudo ip link set {channel} up type can bitrate {bitrate} restart-ms 100`"
    if info.get("info_kind") != "can":
        return Check(FAIL, what, f"{channel} is not a CAN interface ({info.get('info_kind') or link.get('link_type')})")
    if "UP" not in link.get("flags", []):
        return Check(FAIL, what, f"{channel} is down: {up_cmd}, and at boot: docs/deployment.md")
    actual = data.get("bittiming", {}).get("bitrate")
    if actual != bitrate:
        return Check(FAIL, what, f"{channel} runs at {actual} bit/s, the drive at {bitrate}: "
                     f"`sudo ip link set {channel} down`, then {up_cmd}")
    state = data.get("state", "")
    if state in ("BUS-OFF", "STOPPED"):
        return Check(FAIL, what, f"{channel} is {state}: check wiring, termination and the drive's "
                     f"power; restart-ms 100 recovers from bus-off by itself")
    detail = f"up at {actual} bit/s" + (f", {state}" if state else "")
    return Check(WARN if state == "ERROR-PASSIVE" else OK, what, detail)


def check_keys(store, identities: list[str], with_router: bool) -> list[Check]:
    from viena.common.keystore import EXPIRY_WARNING

    if not store.exists():
        return [Check(FAIL, "keys", f"none for car '{store.car}' in {store.dir}: `viena keys init "
                      f"--router-host ADDRESS` (or copy them here with `viena keys export`), or "
                      f"--keys / VIENA_KEYS")]
    checks, good = [], []
    names = identities + (["router"] if with_router else [])
    for name in names:
        try:
            identity = store.router() if name == "router" else store.identity(name)
        except ConfigError as exc:
            checks.append(Check(FAIL, f"keys {name}", str(exc)))
            continue
        left = identity.not_after - _now()
        if left < EXPIRY_WARNING:
            checks.append(Check(WARN, f"keys {name}", f"expires in {left.days} days: "
                                f"`viena keys issue {identity.role} {name} --force` where the CA is"))
        good.append(identity)
    if good:
        first = min(i.not_after for i in good)
        checks.insert(0, Check(OK, "keys", f"{', '.join(i.name for i in good)} valid in {store.dir} "
                                           f"(first expiry {first:%Y-%m-%d})"))
    return checks


def _now():
    import datetime as dt

    return dt.datetime.now(dt.UTC)


def check_router(connect: list[str], keys: str | None, car: str, identity: str | None,
                 profile: str, up: bool) -> tuple[Check, object]:
    """A session with the router, and the session (None if none) for the GNSS check."""
    where = ", ".join(connect)
    args = argparse.Namespace(connect=connect, keys=keys, car=car, identity=identity, config=None)
    try:
        conf = zenoh_config(args, {})
        session = open_session(conf, timeout_s=ROUTER_TIMEOUT_S)
    except InputError as exc:
        return Check(FAIL, f"router {where}", str(exc)), None
    except Unreachable as exc:
        hint = "" if up else f" (the profile is not up: `viena up --profile {profile} -d`)"
        return Check(FAIL, f"router {where}", f"{str(exc).split(': ', 1)[-1]}{hint}"), None
    who = f" as {identity}" if identity and any(e.startswith("tls/") for e in connect) else ""
    return Check(OK, f"router {where}", f"reachable{who}"), session


def check_programs(profile: str) -> Check:
    from viena.programs import rpc

    infos = rpc(profile).getAllProcessInfo()
    bad = [f"{i['name']} {i['statename']}" for i in infos if i["statename"] != "RUNNING"]
    if bad:
        return Check(FAIL, "programs", f"{', '.join(bad)}: `viena logs NAME`, then `viena restart NAME`")
    return Check(OK, "programs", f"{len(infos)} running")


def check_clock() -> Check:
    if shutil.which("timedatectl"):
        done = subprocess.run(["timedatectl", "show", "-p", "NTPSynchronized", "--value"],
                              capture_output=True, text=True)
        if done.returncode == 0 and done.stdout.strip() in ("yes", "no"):
            if done.stdout.strip() == "yes":
                return Check(OK, "clock", "synchronised (timedatectl)")
            return Check(WARN, "clock", "not synchronised: `sudo timedatectl set-ntp true` on a network "
                         "with time, or chrony with the GNSS as its reference (docs/deployment.md, clock)")
    if shutil.which("chronyc"):
        done = subprocess.run(["chronyc", "-n", "tracking"], capture_output=True, text=True)
        leap = re.search(r"Leap status\s*:\s*(.+)", done.stdout)
        if done.returncode == 0 and leap:
            if leap.group(1).strip() == "Normal":
                return Check(OK, "clock", "synchronised (chrony)")
            return Check(WARN, "clock", f"chrony says '{leap.group(1).strip()}': not synchronised yet")
    return Check(WARN, "clock", "unknown: neither timedatectl nor chronyc answered (the offset from "
                 "GNSS time in live fixes is the measure that matters)")


def gnss_offsets(fixes: list[dict]) -> dict[str, float]:
    """Per receiver: the median of host time minus GNSS time (s), over fixes whose time is
    the receiver's (a fix stamped with host time, t == t_host, says nothing)."""
    by_unit: dict[str, list[float]] = {}
    for fix in fixes:
        t, t_host = fix.get("t"), fix.get("t_host")
        if isinstance(t, int) and isinstance(t_host, int) and t != t_host:
            by_unit.setdefault(str(fix.get("unit")), []).append((t_host - t) / 1e9)
    return {unit: statistics.median(values) for unit, values in sorted(by_unit.items())}


def check_gnss_offset(session, car: str, wait_s: float = FIX_WAIT_S) -> Check:
    from viena.services.gnss.model.fix import FIX

    fixes: list[dict] = []

    def on_fix(sample) -> None:
        try:
            fixes.append(FIX.decode(sample.payload.to_bytes()))
        except InputError:
            pass
    sub = session.declare_subscriber(f"viena/{car}/gnss/*/fix", on_fix)
    time.sleep(wait_s)
    sub.undeclare()
    offsets = gnss_offsets(list(fixes))
    if not offsets:
        why = "no fixes" if not fixes else "fixes without receiver time (no GNSS time yet)"
        return Check(WARN, "clock vs GNSS", f"not measured: {why} in {wait_s:g} s")
    worst = max(offsets.values(), key=abs)
    said = ", ".join(f"{u} {o * 1e3:+.0f} ms" for u, o in offsets.items())
    text = f"host minus GNSS time {said} (this includes the receiver's output latency)"
    if abs(worst) >= OFFSET_FAIL_S:
        return Check(FAIL, "clock vs GNSS", f"{text}: the host clock is off; recordings and the "
                     f"estimator need it right (docs/deployment.md, clock)")
    return Check(WARN if abs(worst) >= OFFSET_WARN_S else OK, "clock vs GNSS", text)


def check_disk(name: str, path: Path) -> Check:
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    text = f"{free / 1e9:.1f} GB free at {path}"
    if free < DISK_FAIL_BYTES:
        return Check(FAIL, name, f"{text}: make room (old recordings, logs) before driving")
    return Check(WARN if free < DISK_WARN_BYTES else OK, name, text)


# -- the command --------------------------------------------------------------------------------
def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena doctor", description=__doc__)
    parser.add_argument("--profile", default=None,
                        help="the profile to check (default: the running one, else sim)")
    parser.add_argument("--keys", metavar="DIR",
                        help="the car's key store (default $VIENA_KEYS, else ~/.config/viena/keys/CAR)")
    parser.add_argument("--recordings", type=Path, default=Path.cwd(), metavar="DIR",
                        help="where recordings will be written (default: here)")
    return parser


def run(args: argparse.Namespace) -> int:
    checks = diagnose(args)
    for check in checks:
        print(check.line(), flush=True)
    failed = [c for c in checks if c.status == FAIL]
    if failed:
        print(f"{len(failed)} check(s) failed", file=sys.stderr)
    return 1 if failed else 0


def diagnose(args: argparse.Namespace) -> list[Check]:
    from viena.common.config import load_toml
    from viena.common.keystore import KeyStore

    running = compose.running_profiles()
    profile = args.profile or (running[0] if running else compose.DEFAULT_PROFILE)
    checks = check_versions()
    try:
        conf = compose.profile_file(profile)
    except compose.ComposeError as exc:
        return checks + [Check(FAIL, "profile", str(exc))]
    env, up = profile_environment(profile)
    os.environ.update(env)                         # the profile's settings read them
    programs = profile_programs(conf)
    try:
        toml = load_toml(env["VIENA_SETTINGS"])
    except ConfigError as exc:
        return checks + [Check(FAIL, "profile", str(exc))]
    car = toml.get("car") or env.get("VIENA_CAR") or "elettra"
    checks.append(Check(OK, "profile", f"{profile} ({'up' if up else 'not up'}): "
                        f"{', '.join(p.name for p in programs)}"))

    for program in programs:
        if program.service is None:
            continue
        try:
            settings = program_settings(program, toml, env["VIENA_SETTINGS"])
        except ConfigError as exc:
            checks.append(Check(FAIL, f"settings {program.name}", str(exc)))
            continue
        if program.service in ("gnss", "imu"):
            checks.append(check_serial(program.name, settings.port))
        elif program.service == "steering":
            drive = settings.drive
            checks.append(check_can(drive.interface, drive.channel, drive.bitrate))

    link = env.get("VIENA_LINK", "tcp")
    keys = args.keys or os.environ.get("VIENA_KEYS")
    identity = None
    if link == "tls":
        store = KeyStore.for_car(car, keys)
        names = [p.unit or p.service for p in programs if p.service]
        checks += check_keys(store, names, any(p.service is None for p in programs))
        keys = str(store.dir)
        identity = next((n for n in ("observer", "pilot", "estimator", *names)
                         if (store.dir / f"{n}.pem").exists()), None)
    else:
        checks.append(Check(OK, "keys", "not needed: plain TCP on this machine"
                            if env.get("VIENA_INSECURE") != "1" else "none: INSECURE run (--insecure)"))

    connect = (env.get("VIENA_CONNECT") or compose.client_connect(env) or "tcp/127.0.0.1:7447").split(",")
    session = None
    if link == "tls" and identity is None:
        checks.append(Check(FAIL, f"router {', '.join(connect)}", "not tried: no identity to present (keys above)"))
    else:
        router, session = check_router(connect, keys, car, identity, profile, up)
        checks.append(router)
    if up:
        checks.append(check_programs(profile))
    checks.append(check_clock())
    if session is not None:
        try:
            if any(p.service == "gnss" for p in programs) or up:
                checks.append(check_gnss_offset(session, car))
        finally:
            session.close()
    checks.append(check_disk("disk (recordings)", args.recordings))
    checks.append(check_disk("disk (logs)", run_dir(profile)))
    return checks


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
