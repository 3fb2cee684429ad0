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
    programs   when the profile is up: every program RUNNING (those it leaves off, like
               viena-ntrip without `up --rtk`, STOPPED)
    clock      synchronised (timedatectl, else chronyc), and the host's offset from GNSS
               time in live fixes (`t_host` against `t` of viena.gnss.fix/1)
    receivers  from each GNSS unit's health: the receiver's model, firmware and the
               correction formats it takes, and whether it refused the configured one
    ntrip      with the corrections chain (the profile up with --rtk, or `doctor --rtk`)
               and an [ntrip] caster: its credentials file, that the caster answers with
               its source table, and that the mountpoint is in it (else the nearest and
               the likest names it lists)
    disk       free space where recordings go (--recordings) and where logs go

The profile's settings are read as its programs read them (the service's settings
dataclass, the profile's TOML, the variables `viena up` saved or would set), so a
device moved by VIENA_GNSS0_DEVICE is checked where it now is.
"""
from __future__ import annotations

import argparse
import difflib
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
from typing import TYPE_CHECKING, Any

from viena import compose
from viena.common.errors import ConfigError, InputError
from viena.common.keys import Keys
from viena.common.runstate import run_dir
from viena.common.samples import topics
from viena.common.session import Unreachable, open_session, zenoh_config
from viena.common.versions import version_text

if TYPE_CHECKING:
    import zenoh

OK, WARN, FAIL = "OK", "WARN", "FAIL"
DISK_FAIL_BYTES = 1e9
DISK_WARN_BYTES = 5e9
ROUTER_TIMEOUT_S = 3.0
FIX_WAIT_S = 3.0                    # fixes and GNSS health are listened to this long
NTRIP_TIMEOUT_S = 5.0               # for the caster's answer and its source table
MOUNTPOINTS_SHOWN = 3               # of a caster's mountpoints, when the configured one is not listed
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
    from viena.settings_cli import services

    cls = services().get(program.service) if program.service else None
    if cls is None:
        raise ConfigError(f"no viena service '{program.service}' (viena/services/{program.service}/service.py)")
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
        why = exc.strerror if isinstance(exc, OSError) else None
        return Check(FAIL, what, f"nothing answers ({why or exc}): {hint}")


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
                 profile: str, up: bool) -> tuple[Check, zenoh.Session | None]:
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

    supervisor = rpc(profile)
    infos = supervisor.getAllProcessInfo()
    # a program the profile leaves off (autostart false: viena-ntrip without `up --rtk`) and
    # never started is as it should be
    off = sorted(c["name"] for c in supervisor.getAllConfigInfo() if not c.get("autostart", True))
    left_off = sorted(i["name"] for i in infos if i["name"] in off and i["statename"] == "STOPPED")
    bad = [f"{i['name']} {i['statename']}" for i in infos
           if i["statename"] != "RUNNING" and i["name"] not in left_off]
    if bad:
        return Check(FAIL, "programs", f"{', '.join(bad)}: `viena logs NAME`, then `viena restart NAME`")
    running = len(infos) - len(left_off)
    return Check(OK, "programs", f"{running} running" + (f", {', '.join(left_off)} off" if left_off else ""))


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


@dataclass
class Heard:
    """What the GNSS units said while the doctor listened: their fixes, and the newest
    health of each (by unit)."""

    fixes: list[dict]
    health: dict[str, dict]


def listen_gnss(session, car: str, wait_s: float = FIX_WAIT_S) -> Heard:
    from viena.common.samples.fix import FIX
    from viena.common.samples.health import HEALTH

    heard = Heard([], {})

    def on_fix(sample) -> None:
        try:
            heard.fixes.append(FIX.decode(sample.payload.to_bytes()))
        except InputError:
            pass

    def on_health(sample) -> None:
        try:
            health = HEALTH.decode(sample.payload.to_bytes())
        except InputError:
            return
        heard.health[str(sample.key_expr).split("/")[-2]] = health
    subs = [session.declare_subscriber(Keys(car).of(topics.GNSS_FIX), on_fix),
            session.declare_subscriber(Keys(car).of(topics.HEALTH, service="gnss"), on_health)]
    time.sleep(wait_s)
    for sub in subs:
        sub.undeclare()
    return Heard(list(heard.fixes), dict(heard.health))


def check_gnss_offset(fixes: list[dict], wait_s: float = FIX_WAIT_S) -> Check:
    offsets = gnss_offsets(fixes)
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


def check_receivers(health: dict[str, dict]) -> list[Check]:
    """Per GNSS unit, what its health says of the receiver (NovAtel: from its VERSION
    log): model, firmware, RTK option, the correction formats it takes, the format it
    is given and whether it refused it."""
    checks = []
    for unit, sample in sorted(health.items()):
        said_state = sample.get("state")
        state: dict = said_state if isinstance(said_state, dict) else {}
        model, firmware = state.get("receiver_model"), state.get("receiver_firmware")
        given, refused = state.get("corrections") or "", state.get("corrections_refused") or ""
        if not model and not state.get("receiver_version_error") and not given:
            continue                    # a receiver that says nothing of itself (NMEA, older service)
        what = f"receiver {unit}"
        if not model:
            said = f"model unknown ({state.get('receiver_version_error') or 'no VERSION'})"
        else:
            said = f"{model}, firmware {firmware or '?'}"
            if state.get("receiver_rtk"):
                said += f", RTK {state['receiver_rtk']}"
            formats = state.get("receiver_formats")
            said += f"; takes {', '.join(map(str, formats)) if formats else 'no corrections'}"
        if given:
            said += f"; given {given}" + (f" ({state['corrections_state']})" if state.get("corrections_state") else "")
        if refused:
            checks.append(Check(FAIL, what, f"{said}: refused: {refused}"))
        elif not model and given:
            checks.append(Check(WARN, what, f"{said}: whether it takes {given} is not known"))
        else:
            checks.append(Check(OK, what, said))
    return checks


#: what to do when the caster does not answer, by the NTRIP driver's failure kind
_CASTER_HINTS = {
    "connection_refused": "nothing listens there: the caster is down, or [ntrip] port is wrong "
                          "(casters listen on 2101; with TLS often 443 or 2102)",
    "unreachable": "wrong [ntrip] caster, or no route to it: is this machine online?",
    "tls_errors": "check [ntrip] tls and ca_file: does the caster speak TLS on this port?",
    "unauthorized": "the caster wants a login even for its source table: [ntrip] credentials",
    "not_ntrip": "something that is not an NTRIP caster answers there: check [ntrip] caster and port",
    "dropped": "the caster closed the connection: down or overloaded? try again",
}


def check_ntrip(settings, car: str, position: tuple[float, float] | None = None,
                twin_in_profile: bool = False, timeout_s: float = NTRIP_TIMEOUT_S) -> list[Check]:
    """The NTRIP client's settings against its caster, one line each: the credentials
    file, the caster answering with its source table, the mountpoint in it. `position`
    (lat, lon): the car's, for the distances to the bases."""
    from viena.services.ntrip.driver import (
        CredentialsError,
        LinkError,
        fetch_sourcetable,
        read_credentials,
    )
    from viena.services.ntrip.driver.sourcetable import by_distance, mountpoints

    address = settings.address()
    checks, credentials = [], None
    path = settings.credentials_path(car)
    if path is not None:
        try:
            credentials = read_credentials(path)
            checks.append(Check(OK, f"ntrip credentials {path}", "one login, readable by its owner only"))
        except CredentialsError as exc:
            if twin_in_profile and not path.exists():
                checks.append(Check(WARN, f"ntrip credentials {path}", "not there yet: the caster's twin "
                                    "writes it when it starts"))
            else:
                checks.append(Check(FAIL, f"ntrip credentials {path}", f"{exc} (viena-ntrip will not start)"))
    caster = f"ntrip caster {address.caster}" + (" (TLS)" if address.tls else "")
    mount = f"ntrip mountpoint {address.mountpoint}"
    try:
        table = mountpoints(fetch_sourcetable(address, credentials, timeout_s))
    except LinkError as exc:
        hint = _CASTER_HINTS.get(exc.kind, "")
        if twin_in_profile and exc.kind == "connection_refused":
            hint = "the caster's twin is not up: `viena up --rtk`"
        checks.append(Check(FAIL, caster, f"{exc.why}" + (f": {hint}" if hint else "")))
        checks.append(Check(WARN, mount, "not checked: the caster gave no source table"))
        return checks
    checks.append(Check(OK, caster, f"answers NTRIP {address.version}: {len(table)} mountpoint"
                                    f"{'s' if len(table) != 1 else ''} in its source table"))
    distances = by_distance(table, *position) if position else [(m, None) for m in table]
    for entry, km in distances:
        if entry.name == address.mountpoint:
            where = f", {km:.1f} km from the car" if km is not None else ""
            gga = "; wants the car's position (gga_interval_s > 0)" if entry.wants_gga else ""
            warn = entry.wants_gga and not settings.gga_interval_s > 0
            checks.append(Check(WARN if warn else OK, mount, f"listed: {entry.format or '?'} "
                                f"({entry.details or '-'}), {entry.nav_systems or '?'}{where}{gga}"))
            return checks
    listed = ", ".join(m.name if km is None else f"{m.name} ({km:.{1 if km < 10 else 0}f} km)"
                       for m, km in distances[:MOUNTPOINTS_SHOWN])
    likest = difflib.get_close_matches(address.mountpoint, [m.name for m in table], n=MOUNTPOINTS_SHOWN, cutoff=0.5)
    said = f"not in the caster's source table; {'nearest' if position else 'it lists'}: {listed or 'none'}"
    if likest:
        said += f"; names like it: {', '.join(likest)}"
    checks.append(Check(FAIL, mount, f"{said} (`viena ntrip sources {address.caster}`)"))
    return checks


def car_position(fixes: list[dict]) -> tuple[float, float] | None:
    """The median (lat, lon) of the valid fixes heard, or None."""
    valid = [(f["lat_deg"], f["lon_deg"]) for f in fixes if f.get("valid") is True]
    if not valid:
        return None
    return statistics.median(lat for lat, _ in valid), statistics.median(lon for _, lon in valid)


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
    parser.add_argument("--rtk", action="store_true",
                        help="check the corrections chain as `viena up --rtk` runs it (the NTRIP caster); "
                             "a profile up with --rtk is checked so anyway")
    return parser


def run(args: argparse.Namespace) -> int:
    checks = diagnose(args)
    for check in checks:
        print(check.line(), flush=True)
    failed = [c for c in checks if c.status == FAIL]
    if failed:
        print(f"{len(failed)} check(s) failed", file=sys.stderr)
    return 1 if failed else 0


@dataclass(frozen=True)
class ProfileRun:
    """The profile as its programs will see it: its variables, whether it is up, its
    programs and its settings."""
    name: str
    env: dict[str, str]
    up: bool
    programs: list[Program]
    toml: dict
    car: str

    @property
    def settings_path(self) -> str:
        return self.env["VIENA_SETTINGS"]


def read_profile(args: argparse.Namespace) -> ProfileRun | Check:
    """The profile asked for (else the one running, else the default), its variables put in
    this process's environment (its settings read them); a FAIL if it cannot be read."""
    from viena.common.config import load_toml

    running = compose.running_profiles()
    profile = args.profile or (running[0] if running else compose.DEFAULT_PROFILE)
    try:
        conf = compose.profile_file(profile)
    except compose.ComposeError as exc:
        return Check(FAIL, "profile", str(exc))
    env, up = profile_environment(profile)
    if getattr(args, "rtk", False) and not up:
        env.update(compose.rtk_environment(env))
    os.environ.update(env)                         # the profile's settings read them
    programs = profile_programs(conf)
    try:
        toml = load_toml(env["VIENA_SETTINGS"])
    except ConfigError as exc:
        return Check(FAIL, "profile", str(exc))
    car = toml.get("car") or env.get("VIENA_CAR") or "elettra"
    return ProfileRun(profile, env, up, programs, toml, car)


def check_devices(run: ProfileRun) -> tuple[list[Check], Any]:
    """Each program's settings, and the devices they open; and the NTRIP client's settings,
    if it runs (None if not)."""
    checks: list[Check] = []
    ntrip = None
    for program in run.programs:
        if program.service is None:
            continue
        try:
            settings = program_settings(program, run.toml, run.settings_path)
        except ConfigError as exc:
            checks.append(Check(FAIL, f"settings {program.name}", str(exc)))
            continue
        if program.service == "ntrip":
            ntrip = settings
        elif program.service in ("gnss", "imu"):
            checks.append(check_serial(program.name, settings.port))
        elif program.service == "steering":
            drive = settings.drive
            checks.append(check_can(drive.interface, drive.channel, drive.bitrate))
    return checks, ntrip


def check_link(run: ProfileRun, keys: str | None) -> tuple[list[Check], zenoh.Session | None]:
    """The keys (on a TLS profile) and a session with the router, kept open (None if none)
    for the checks that listen."""
    from viena.common.keystore import KeyStore

    checks: list[Check] = []
    link = run.env.get("VIENA_LINK", "tcp")
    identity = None
    if link == "tls":
        store = KeyStore.for_car(run.car, keys)
        names = [p.unit or p.service for p in run.programs if p.service]
        checks += check_keys(store, names, any(p.service is None for p in run.programs))
        keys = str(store.dir)
        identity = next((n for n in ("observer", "pilot", "estimator", *names)
                         if (store.dir / f"{n}.pem").exists()), None)
    else:
        checks.append(Check(OK, "keys", "not needed: plain TCP on this machine"
                            if run.env.get("VIENA_INSECURE") != "1" else "none: INSECURE run (--insecure)"))
    connect = (run.env.get("VIENA_CONNECT") or compose.client_connect(run.env) or "tcp/127.0.0.1:7447").split(",")
    if link == "tls" and identity is None:
        checks.append(Check(FAIL, f"router {', '.join(connect)}", "not tried: no identity to present (keys above)"))
        return checks, None
    router, session = check_router(connect, keys, run.car, identity, run.name, run.up)
    checks.append(router)
    return checks, session


def check_corrections(run: ProfileRun, ntrip, fixes: list[dict]) -> list[Check]:
    """The corrections chain, when the profile runs the NTRIP client (`ntrip`: its settings)."""
    if ntrip is None:
        return []
    if run.env.get("VIENA_RTK") != "true":
        return [Check(OK, "ntrip", "off: the profile runs without corrections (`viena up --rtk`; "
                      "`viena doctor --rtk` checks the caster)")]
    if not ntrip.caster:
        return [Check(FAIL, "ntrip", "no caster: give it in the profile's settings ([ntrip] caster)")]
    return check_ntrip(ntrip, run.car, car_position(fixes),
                       twin_in_profile=any(p.name == "caster" for p in run.programs))


def diagnose(args: argparse.Namespace) -> list[Check]:
    checks = check_versions()
    run = read_profile(args)
    if isinstance(run, Check):
        return checks + [run]
    checks.append(Check(OK, "profile", f"{run.name} ({'up' if run.up else 'not up'}): "
                        f"{', '.join(p.name for p in run.programs)}"))
    devices, ntrip = check_devices(run)
    checks += devices
    link, session = check_link(run, args.keys or os.environ.get("VIENA_KEYS"))
    checks += link
    if run.up:
        checks.append(check_programs(run.name))
    checks.append(check_clock())
    heard = Heard([], {})
    if session is not None:
        try:
            if any(p.service == "gnss" for p in run.programs) or run.up:
                heard = listen_gnss(session, run.car)
                checks.append(check_gnss_offset(heard.fixes))
        finally:
            session.close()
    checks += check_receivers(heard.health)
    checks += check_corrections(run, ntrip, heard.fixes)
    checks.append(check_disk("disk (recordings)", args.recordings))
    checks.append(check_disk("disk (logs)", run_dir(run.name)))
    return checks


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
