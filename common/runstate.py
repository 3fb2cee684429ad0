"""Where a running profile keeps its state, so any command can find it.

`viena up` writes the profile's variables to `<run>/env.json` (the run directory is
$VIENA_RUN, else ~/.local/state/viena/<profile>), supervisord writes its pid beside it.
From them every later command knows which profiles run, with which ports, keys and link,
and where a client of the profile connects (VIENA_CONNECT), so nobody types a port that
`--free-ports` chose.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from viena.common.paths import compose_dir


def profiles() -> list[str]:
    return sorted(p.stem for p in compose_dir().glob("*.conf"))


def state_root() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(base) / "viena"


def run_dir(profile: str) -> Path:
    return Path(os.environ.get("VIENA_RUN") or state_root() / profile)


def read_environment(profile: str) -> dict[str, str] | None:
    """The variables `viena up` saved for `profile`, or None if it never ran here."""
    try:
        env = json.loads((run_dir(profile) / "env.json").read_text())
    except (OSError, ValueError):
        return None
    return env if env.get("VIENA_PROFILE") == profile else None   # VIENA_RUN shared by several


def supervisord_pid(profile: str) -> int | None:
    """The pid of the profile's running supervisord, if it runs."""
    if read_environment(profile) is None:
        return None
    try:
        pid = int((run_dir(profile) / "supervisord.pid").read_text().strip())
        os.kill(pid, 0)
        return pid
    except (OSError, ValueError):
        return None


def process_alive(pid: int) -> bool:
    """Whether `pid` is still a process (a zombie waiting for its parent is not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except (OSError, IndexError):
        return True


def running_profiles() -> list[str]:
    return [p for p in profiles() if supervisord_pid(p)]


def running_environment() -> dict[str, str] | None:
    """The saved variables of the profile running on this machine (the first, if several),
    or None when none runs."""
    for profile in running_profiles():
        return read_environment(profile)
    return None


def running_connect() -> tuple[list[str], dict[str, str]] | None:
    """Where a client of the running profile connects, and that profile's variables."""
    env = running_environment()
    if not env or not env.get("VIENA_CONNECT"):
        return None
    return env["VIENA_CONNECT"].split(","), env
