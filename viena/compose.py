"""`viena up/down/status/logs`: a thin wrapper around supervisord and supervisorctl.

A profile is a supervisord file `compose/<profile>.conf` plus the settings its programs
read (`compose/<profile>.toml`, passed as VIENA_SETTINGS). Programs are defined once, in
`compose/programs/*.ini`, and a profile includes those it runs. Profiles use environment variables for what differs
between runs: VIENA_RUN (the run directory: socket, pid, logs), VIENA_PYTHON, and ports
named VIENA_*_PORT. `up` fixes them once and writes them to `<run>/env.json`, so the
later commands (and supervisorctl, which re-reads the same file) see the same values.
"""
from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from viena.paths import compose_dir
from viena.profile_security import SecurityRefusal, secure_environment

DEFAULT_PROFILE = "sim"
_PORT_VAR = re.compile(r"(?:%\(ENV_|\$\{)(VIENA_[A-Z0-9_]*PORT)(?:\)s|:-(\d+)\}|\})")
_LINK_DEFAULT = re.compile(r"\$\{VIENA_LINK:-(tls|tcp)\}")


class ComposeError(Exception):
    """Something a person can fix: said in one line."""


def profiles() -> list[str]:
    return sorted(p.stem for p in compose_dir().glob("*.conf"))


def profile_file(profile: str) -> Path:
    path = compose_dir() / f"{profile}.conf"
    if not path.exists():
        raise ComposeError(f"no profile '{profile}' (have: {', '.join(profiles())})")
    return path


def state_root() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(base) / "viena"


def run_dir(profile: str) -> Path:
    return Path(os.environ.get("VIENA_RUN") or state_root() / profile)


def port_variables(profile: str) -> dict[str, int | None]:
    """VIENA_*_PORT names a profile uses, with the defaults its files give."""
    found: dict[str, int | None] = {}
    for path in (compose_dir() / f"{profile}.conf", compose_dir() / f"{profile}.toml"):
        if path.exists():
            for name, default in _PORT_VAR.findall(path.read_text()):
                if default or name not in found:
                    found[name] = int(default) if default else found.get(name)
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def link_default(profile: str) -> str:
    """tls or tcp: what the profile's settings say its links are unless told otherwise."""
    path = compose_dir() / f"{profile}.toml"
    m = _LINK_DEFAULT.search(path.read_text()) if path.exists() else None
    return m.group(1) if m else "tcp"


def environment(profile: str, free_ports: bool = False) -> dict[str, str]:
    """The variables a profile's files refer to; the caller's environment wins."""
    env = {
        "VIENA_RUN": str(run_dir(profile)),
        "VIENA_PYTHON": sys.executable,
        "VIENA_PROFILE": profile,
        "VIENA_SETTINGS": str(compose_dir() / f"{profile}.toml"),
        "VIENA_LINK": os.environ.get("VIENA_LINK") or link_default(profile),
    }
    for name, default in port_variables(profile).items():
        if name in os.environ:
            env[name] = os.environ[name]
        elif free_ports or default is None:
            env[name] = str(free_port())
        else:
            env[name] = str(default)
    return env


def saved_environment(profile: str) -> dict[str, str]:
    path = run_dir(profile) / "env.json"
    if not path.exists():
        raise ComposeError(f"profile '{profile}' is not up (no {path})")
    return json.loads(path.read_text())


def _supervisor_env(env: dict[str, str]) -> dict[str, str]:
    full = dict(os.environ)
    full.update(env)
    return full


def supervisord_pid(profile: str) -> int | None:
    """The pid of the profile's running supervisord, if it runs."""
    run = run_dir(profile)
    try:
        if json.loads((run / "env.json").read_text()).get("VIENA_PROFILE") != profile:
            return None                         # VIENA_RUN shared by several profiles
    except (OSError, ValueError):
        return None
    pidfile = run / "supervisord.pid"
    try:
        pid = int(pidfile.read_text().strip())
        os.kill(pid, 0)
        return pid
    except (OSError, ValueError):
        return None


def up(profile: str = DEFAULT_PROFILE, detach: bool = False, free_ports: bool = False,
       secure: bool = False, insecure: bool = False, keys: str | None = None) -> int:
    conf = profile_file(profile)
    if supervisord_pid(profile):
        raise ComposeError(f"profile '{profile}' is already up: `viena down --profile {profile}` first")
    env = environment(profile, free_ports)
    try:
        env.update(secure_environment(conf, env, secure, insecure, keys))
    except SecurityRefusal as exc:
        raise ComposeError(f"profile {profile}: {exc}") from None
    run = Path(env["VIENA_RUN"])
    run.mkdir(parents=True, exist_ok=True)
    (run / "env.json").write_text(json.dumps(env, indent=1))
    cmd = [sys.executable, "-m", "supervisor.supervisord", "-c", str(conf)]
    ports = ", ".join(f"{k}={v}" for k, v in env.items() if k.endswith("_PORT"))
    print(f"viena: profile {profile} up ({ports}; {_security_words(env)}); logs in {run}",
          file=sys.stderr, flush=True)
    if detach:
        subprocess.run(cmd, env=_supervisor_env(env), check=True)
        return wait_running(profile)
    proc = subprocess.Popen(cmd + ["-n"], env=_supervisor_env(env))
    # Ctrl-C reaches supervisord too (same process group): it stops every program, then us.
    while True:
        try:
            return proc.wait()
        except KeyboardInterrupt:
            print("viena: stopping (Ctrl-C)", file=sys.stderr, flush=True)
            proc.send_signal(signal.SIGINT)


def _security_words(env: dict[str, str]) -> str:
    if env["VIENA_LINK"] == "tls":
        return f"TLS and access control, keys in {env['VIENA_KEYS']}"
    if env.get("VIENA_INSECURE") == "1":
        return "INSECURE: no TLS, no access control"
    return "plain TCP on this machine only"


def ctl(profile: str, *args: str, capture: bool = False) -> subprocess.CompletedProcess:
    env = saved_environment(profile)
    # supervisorctl does not follow [include]; talk to the socket directly
    url = f"unix://{env['VIENA_RUN']}/supervisor.sock"
    cmd = [sys.executable, "-m", "supervisor.supervisorctl", "-s", url, *args]
    return subprocess.run(cmd, env=_supervisor_env(env), text=True,
                          capture_output=capture)


def program_states(profile: str) -> dict[str, str]:
    out = ctl(profile, "status", capture=True).stdout
    return {line.split()[0]: line.split()[1] for line in out.splitlines() if len(line.split()) > 1}


def wait_running(profile: str, timeout: float = 30.0) -> int:
    """Like `docker compose up --wait`: return once every program is up (or has failed)."""
    end = time.monotonic() + timeout
    states: dict[str, str] = {}
    while time.monotonic() < end:
        states = program_states(profile)
        if states and not any(s in ("STARTING", "BACKOFF") for s in states.values()):
            break
        time.sleep(0.2)
    bad = {name: s for name, s in states.items() if s != "RUNNING"}
    if bad:
        print("viena: not running: " + ", ".join(f"{n} {s}" for n, s in bad.items())
              + f" (see `viena logs NAME --profile {profile}`)", file=sys.stderr)
        return 1
    return 0


def status(profile: str) -> int:
    if not supervisord_pid(profile):
        print(f"profile '{profile}' is down")
        return 3
    return ctl(profile, "status").returncode


def logs(profile: str, program: str, follow: bool = False) -> int:
    if follow:
        return ctl(profile, "tail", "-f", program).returncode
    path = Path(saved_environment(profile)["VIENA_RUN"]) / f"{program}.log"
    if not path.exists():
        raise ComposeError(f"no log for '{program}' in {path.parent}")
    sys.stdout.write(path.read_text()[-20000:])
    return 0


def update(profile: str) -> int:
    """Apply edits of a running profile (a program moved in or out): supervisord re-reads
    its files, starts what was added, stops what was removed, leaves the rest running."""
    if not supervisord_pid(profile):
        raise ComposeError(f"profile '{profile}' is not up")
    done = ctl(profile, "update")
    return done.returncode or wait_running(profile)


def down(profile: str, timeout: float = 15.0) -> int:
    pid = supervisord_pid(profile)
    if pid is None:
        print(f"profile '{profile}' is already down")
        return 0
    ctl(profile, "shutdown", capture=True)
    end = time.monotonic() + timeout
    while time.monotonic() < end and supervisord_pid(profile):
        time.sleep(0.1)
    if supervisord_pid(profile):
        os.kill(pid, signal.SIGTERM)
        raise ComposeError(f"supervisord (pid {pid}) did not stop in {timeout:.0f} s; sent SIGTERM")
    print(f"profile '{profile}' is down")
    return 0


def running_profiles() -> list[str]:
    return [p for p in profiles() if supervisord_pid(p)]
