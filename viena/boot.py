"""`viena service install --profile pi`: start a profile at boot, as a systemd unit.

    viena service install --profile pi      write, enable and (--now) start viena-pi.service
    viena service uninstall --profile pi    stop, disable and remove it
    viena service show --profile pi         print the unit it would write

The unit runs `viena up --profile PROFILE` in the foreground, with this installation's
Python, as the person who installs it (under sudo: the one who ran sudo), so `viena
status`, `viena logs` and the key store (~/.config/viena/keys) are theirs as when typed
by hand. systemd starts it once the network is up, restarts it 5 s after a failure, and
stops it by SIGTERM to `viena up` alone (KillMode=mixed), which hands it to supervisord:
every program stops in order within its stopwaitsecs; whatever is left after 30 s is
killed.

A system unit (/etc/systemd/system, needs root) is the default: it starts at boot with
nobody logged in, and may add the `dialout` group for the serial devices. `--user` writes a
user unit (~/.config/systemd/user) instead, for machines where root is not at hand; it
starts at boot only after `loginctl enable-linger USER`. docs/deployment.md has the rest
(serial names, can0 at boot).
"""
from __future__ import annotations

import argparse
import getpass
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from viena.common.versions import version_text
from viena.tool import Fail, guarded

SYSTEM_DIR = Path("/etc/systemd/system")
STOP_TIMEOUT_S = 30
RESTART_DELAY_S = 5


def unit_name(profile: str) -> str:
    return f"viena-{profile}.service"


def user_dir() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "systemd" / "user"


def run_as() -> str:
    """Who the unit runs as: whoever ran sudo, else whoever runs this."""
    return os.environ.get("SUDO_USER") or getpass.getuser()


def unit_text(profile: str, user_unit: bool, keys: str | None = None, insecure: bool = False,
              python: str = sys.executable) -> str:
    """The unit file: `viena up` in the foreground, restarted on failure, stopped cleanly."""
    up = [python, "-m", "viena.cli", "up", "--profile", profile, *(["--insecure"] if insecure else [])]
    lines = [
        f"# {unit_name(profile)}: made by `viena service install --profile {profile}` (which",
        f"# rewrites it) with viena {version_text()}",
        "[Unit]",
        f"Description=viena: the car's processes (profile {profile})",
    ]
    if not user_unit:
        lines += ["Wants=network-online.target", "After=network-online.target time-sync.target"]
    lines += [
        "",
        "[Service]",
        "Type=exec",
    ]
    if not user_unit:
        lines += [f"User={run_as()}", "SupplementaryGroups=dialout"]
    lines += [
        "WorkingDirectory=~",
        "Environment=PYTHONUNBUFFERED=1",
        *([f"Environment={_quoted('VIENA_KEYS=' + str(Path(keys).expanduser().resolve()))}"] if keys else []),
        f"ExecStart={shlex.join(up)}",
        "# SIGTERM to `viena up` alone: it has supervisord stop every program in order",
        "KillMode=mixed",
        "KillSignal=SIGTERM",
        f"TimeoutStopSec={STOP_TIMEOUT_S}",
        "Restart=on-failure",
        f"RestartSec={RESTART_DELAY_S}",
        "",
        "[Install]",
        f"WantedBy={'default.target' if user_unit else 'multi-user.target'}",
    ]
    return "\n".join(lines) + "\n"


def _quoted(assignment: str) -> str:
    return f'"{assignment}"' if " " in assignment else assignment


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena service", description=__doc__)
    parser.add_argument("action", choices=("install", "uninstall", "show"))
    parser.add_argument("--profile", default="pi", help="the profile to start at boot (default pi)")
    parser.add_argument("--user", action="store_true",
                        help="a user unit (~/.config/systemd/user; needs `loginctl enable-linger`) "
                             "instead of a system unit (/etc/systemd/system; needs root)")
    parser.add_argument("--keys", metavar="DIR", help="the car's key store, if not the default")
    parser.add_argument("--insecure", action="store_true",
                        help="run the profile without TLS (`viena up --insecure`): a trusted network only")
    parser.add_argument("--dir", type=Path, metavar="DIR",
                        help="write the unit here and leave systemd alone (to look at it, or to copy it)")
    parser.add_argument("--now", action="store_true", help="install: start it now too")
    parser.add_argument("--no-enable", action="store_true", help="install: do not enable it at boot")
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena service", _run, args)


def _run(args: argparse.Namespace) -> int:
    from viena.compose import ComposeError, profile_file

    try:
        profile_file(args.profile)
    except ComposeError as exc:
        raise Fail(str(exc), 2) from None
    text = unit_text(args.profile, args.user, args.keys, args.insecure)
    if args.action == "show":
        sys.stdout.write(text)
        return 0
    directory = args.dir or (user_dir() if args.user else SYSTEM_DIR)
    path = directory / unit_name(args.profile)
    systemd = args.dir is None
    if args.action == "install":
        return _install(path, text, args, systemd)
    return _uninstall(path, args, systemd)


def _install(path: Path, text: str, args: argparse.Namespace, systemd: bool) -> int:
    replaced = path.exists() and path.read_text() != text
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    except PermissionError:
        again = (shlex.join([sys.executable, "-m", "viena.cli", *sys.argv[1:]]) if sys.argv[1:]
                 else "viena service install")
        raise Fail(f"cannot write {path}: a system unit needs root (`sudo {again}`; it will run as "
                   f"{run_as()}), or --user for a user unit") from None
    print(f"{'replaced' if replaced else 'wrote'} {path}")
    name = path.name
    if not systemd:
        if args.user:
            print(f"(left systemd alone: `cp {path} {user_dir()}/ && systemctl --user daemon-reload "
                  f"&& systemctl --user enable --now {name}`)")
        else:
            print(f"(left systemd alone: `sudo cp {path} {SYSTEM_DIR}/ && sudo systemctl daemon-reload "
                  f"&& sudo systemctl enable --now {name}`)")
        return 0
    steps = [["daemon-reload"]]
    if not args.no_enable:
        steps.append(["enable", name])
    if args.now:
        steps.append(["restart", name])
    _systemctl(steps, args.user)
    when = "at boot" if not args.no_enable else "when started"
    print(f"{name} runs `viena up --profile {args.profile}` {when}"
          f"{' (and now)' if args.now else f'; `systemctl {_scope(args.user)}start {name}` starts it now'}; "
          f"`journalctl {_scope(args.user)}-u {name}` shows what it says")
    if args.user:
        print(f"a user unit starts at boot only with lingering on: `sudo loginctl enable-linger {run_as()}`")
    return 0


def _uninstall(path: Path, args: argparse.Namespace, systemd: bool) -> int:
    if systemd and path.exists():
        _systemctl([["disable", "--now", path.name]], args.user)
    try:
        path.unlink()
    except FileNotFoundError:
        print(f"{path} is not there: nothing to remove")
        return 0
    except PermissionError:
        raise Fail(f"cannot remove {path}: it needs root (sudo)") from None
    if systemd:
        _systemctl([["daemon-reload"]], args.user)
    print(f"removed {path}")
    return 0


def _scope(user: bool) -> str:
    return "--user " if user else ""


def _systemctl(steps: list[list[str]], user: bool) -> None:
    tool = shutil.which("systemctl")
    for step in steps:
        cmd = ["systemctl", *(["--user"] if user else []), *step]
        if tool is None:
            raise Fail(f"no systemctl on this machine: run `{shlex.join(cmd)}` where systemd runs")
        done = subprocess.run([tool, *cmd[1:]], capture_output=True, text=True)
        if done.returncode != 0:
            why = (done.stderr or done.stdout).strip().splitlines()
            raise Fail(f"`{shlex.join(cmd)}` failed: {why[-1] if why else f'status {done.returncode}'}")
