"""`viena up/down/status/logs`: a thin wrapper around supervisord and supervisorctl.

A profile is a supervisord file `compose/<profile>.conf` plus the settings its programs
read (`compose/<profile>.toml`, passed as VIENA_SETTINGS). Programs are defined once, in
`compose/programs/*.ini`, and a profile includes those it runs. Profiles use environment variables for what differs
between runs: VIENA_RUN (the run directory: socket, pid, logs), VIENA_PYTHON, and ports
named VIENA_*_PORT. `up` fixes them once and writes them to `<run>/env.json`, so the
later commands (and supervisorctl, which re-reads the same file) see the same values,
and so does every tool that connects without --connect: env.json also holds where a
client of the profile connects (VIENA_CONNECT) and the variables its settings named.
One program at a time (logs, restart, stop, start, and whether it is really up):
viena/programs.py.
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
import xmlrpc.client
from pathlib import Path

from viena import programs
from viena.common.config import load_toml
from viena.common.errors import ConfigError
from viena.common.paths import compose_dir
from viena.common.runstate import (  # noqa: F401
    process_alive,
    profiles,
    read_environment,
    run_dir,
    running_profiles,
    state_root,
    supervisord_pid,
)
from viena.profile_security import SecurityRefusal, secure_environment
from viena.profile_security import programs as programs_in

DEFAULT_PROFILE = "sim"
_PORT_VAR = re.compile(r"(?:%\(ENV_|\$\{)(VIENA_[A-Z0-9_]*PORT)(?:\)s|:-(\d+)\}|\})")
_RECORD_ALWAYS = re.compile(r"^record\s*=\s*true\b", re.M)
_LINK_DEFAULT = re.compile(r"\$\{VIENA_LINK:-(tls|tcp)\}")
_SETTINGS_VAR = re.compile(r"\$\{([A-Z][A-Z0-9_]*)")


class ComposeError(Exception):
    """Something a person can fix: said in one line."""


def profile_file(profile: str) -> Path:
    path = compose_dir() / f"{profile}.conf"
    if not path.exists():
        raise ComposeError(f"no profile '{profile}' (have: {', '.join(profiles())})")
    return path


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


def records_always(profile: str) -> bool:
    """Whether the profile's settings run the black box always (`record = true`)."""
    path = compose_dir() / f"{profile}.toml"
    return bool(_RECORD_ALWAYS.search(path.read_text())) if path.exists() else False


def environment(profile: str, free_ports: bool = False) -> dict[str, str]:
    """The variables a profile's files refer to; the caller's environment wins."""
    env = {
        "VIENA_RUN": str(run_dir(profile)),
        "VIENA_PYTHON": sys.executable,
        "VIENA_PROFILE": profile,
        "VIENA_SETTINGS": str(compose_dir() / f"{profile}.toml"),
        "VIENA_LINK": os.environ.get("VIENA_LINK") or link_default(profile),
        # where a profile's router listens (pi.conf): every interface, unless told one
        "VIENA_ROUTER_HOST": os.environ.get("VIENA_ROUTER_HOST") or "0.0.0.0",
        # the corrections chain (programs/ntrip.ini, caster.ini): off unless `up --rtk`
        "VIENA_RTK": "false",
        # the black box (programs/recorder.ini): on where the settings say `record = true`
        # (the pi profile), else when `up --record`
        "VIENA_RECORD": "true" if records_always(profile) else "false",
    }
    settings = compose_dir() / f"{profile}.toml"
    named = _SETTINGS_VAR.findall(settings.read_text()) if settings.exists() else []
    env.update({name: os.environ[name] for name in named if name in os.environ and name not in env})
    for name, default in port_variables(profile).items():
        if name in os.environ:
            env[name] = os.environ[name]
        elif free_ports or default is None:
            env[name] = str(free_port())
        else:
            env[name] = str(default)
    return env


def rtk_environment(env: dict[str, str]) -> dict[str, str]:
    """What `up --rtk` changes: the NTRIP client (and in the sim the caster's twin) start,
    and the receivers take RTCM 3 unless the caller's VIENA_RTK_FORMAT says otherwise (the
    settings read it: compose/sim.toml [gnss] corrections), and the pilot follows only on
    an RTK float or fixed solution ([pilot] min_solution), with Stanley ([pilot] controller:
    on centimetre positions the tracker's own error is what is left)."""
    return {"VIENA_RTK": "true", "VIENA_RTK_FORMAT": os.environ.get("VIENA_RTK_FORMAT") or "RTCMV3",
            "VIENA_RTK_MIN_SOLUTION": os.environ.get("VIENA_RTK_MIN_SOLUTION") or "float",
            "VIENA_PILOT_CONTROLLER": os.environ.get("VIENA_PILOT_CONTROLLER") or "stanley"}


def _secure_environment(conf: Path, env: dict[str, str], secure: bool, insecure: bool, keys: str | None,
                        record: bool) -> dict[str, str]:
    """secure_environment; a key store made before the black box (no `recorder` identity)
    starts the car without it, with one line saying how to add it, unless --record asked."""
    try:
        return secure_environment(conf, env, secure, insecure, keys)
    except SecurityRefusal as exc:
        if record or env.get("VIENA_RECORD") != "true" or exc.failed != ("recorder",):
            raise
    print("viena up: the key store has no `recorder` identity (made before the black box): starting "
          "without it. On the machine that keeps the CA: `viena keys issue recorder recorder`, then export "
          "it to this car (docs/deployment.md)", file=sys.stderr, flush=True)
    env["VIENA_RECORD"] = "false"
    return secure_environment(conf, env, secure, insecure, keys)


def saved_environment(profile: str) -> dict[str, str]:
    env = read_environment(profile)
    if env is None:
        raise ComposeError(f"profile '{profile}' is not up (no {run_dir(profile) / 'env.json'})")
    return env


def client_connect(env: dict[str, str]) -> str | None:
    """Where a client of the profile connects (its settings' [zenoh] connect), as this
    run's variables make it; comma-separated if several."""
    try:
        table = load_toml(env["VIENA_SETTINGS"]).get("zenoh", {})
    except ConfigError:
        return None
    connect = table.get("connect") if isinstance(table, dict) else None
    if isinstance(connect, str):
        connect = [connect]
    return ",".join(connect) if isinstance(connect, list) and connect else None


def _supervisor_env(env: dict[str, str]) -> dict[str, str]:
    full = dict(os.environ)
    full.update(env)
    return full


def up(profile: str = DEFAULT_PROFILE, detach: bool = False, free_ports: bool = False,
       secure: bool = False, insecure: bool = False, keys: str | None = None, rtk: bool = False,
       record: bool = False) -> int:
    conf = profile_file(profile)
    if supervisord_pid(profile):
        raise ComposeError(f"profile '{profile}' is already up: `viena down --profile {profile}` first")
    env = environment(profile, free_ports)
    if rtk:
        env.update(rtk_environment(env))
    if record:
        env["VIENA_RECORD"] = "true"
    try:
        env.update(_secure_environment(conf, env, secure, insecure, keys, record))
    except SecurityRefusal as exc:
        raise ComposeError(f"profile {profile}: {exc}") from None
    run = Path(env["VIENA_RUN"])
    run.mkdir(parents=True, exist_ok=True)
    os.environ.update(env)                      # what supervisord and its programs will see
    connect = client_connect(env)
    if connect:
        env["VIENA_CONNECT"] = connect
    (run / "env.json").write_text(json.dumps(env, indent=1))
    cmd = [sys.executable, "-m", "supervisor.supervisord", "-c", str(conf)]
    ports = ", ".join(f"{k}={v}" for k, v in env.items() if k.endswith("_PORT"))
    print(f"viena: profile {profile} up ({ports}; {_security_words(env)}); logs in {run}",
          file=sys.stderr, flush=True)
    if detach:
        started = time.monotonic()
        said_before = programs.log_sizes(profile, programs_in(conf))
        if subprocess.run(cmd, env=_supervisor_env(env)).returncode != 0:     # it said why, above
            raise ComposeError(f"supervisord did not start profile {profile} ({conf})")
        status = wait_running(profile, said_before=said_before)
        if status == 0:
            print(f"viena: every program of {profile} is up ({time.monotonic() - started:.1f} s); "
                  f"`viena status`, `viena logs NAME`, `viena down`", file=sys.stderr)
        return status
    return _foreground(cmd, env)


def _foreground(cmd: list[str], env: dict[str, str]) -> int:
    """supervisord in the foreground until it ends. Ctrl-C reaches it too (same process
    group); SIGTERM (systemd stopping the unit) is handed on: either way it stops every
    program in order, then itself, then us."""
    proc = subprocess.Popen(cmd + ["-n"], env=_supervisor_env(env))

    def on_term(signum, _frame) -> None:
        print("viena: stopping (SIGTERM)", file=sys.stderr, flush=True)
        proc.send_signal(signal.SIGTERM)
    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        while True:
            try:
                return proc.wait()
            except KeyboardInterrupt:
                print("viena: stopping (Ctrl-C)", file=sys.stderr, flush=True)
                proc.send_signal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)


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


def wait_running(profile: str, names: list[str] | None = None,
                 said_before: dict[str, int] | None = None) -> int:
    """Like `docker compose up --wait`, and honest: once every program (or those named)
    has stayed up past its start, 0; else 1, having said which did not and why."""
    return programs.report(profile, programs.wait_settled(profile, names, said_before))


def status(profile: str) -> int:
    if not supervisord_pid(profile):
        print(f"profile '{profile}' is down")
        return 3
    return ctl(profile, "status").returncode


def one_program(action: str, profile: str, program: str, follow: bool = False) -> int:
    """`viena logs|restart|stop|start NAME`: one program of a profile."""
    conf = profile_file(profile)
    if action == "logs":
        saved_environment(profile)                  # says so if the profile never ran here
    elif not supervisord_pid(profile):
        raise ComposeError(f"profile '{profile}' is not up: `viena up --profile {profile}` first")
    try:
        if action == "logs":
            return programs.logs(profile, conf, program, follow)
        return {"restart": programs.restart, "stop": programs.stop,
                "start": programs.start}[action](profile, conf, program)
    except programs.ProgramError as exc:
        raise ComposeError(str(exc)) from None


def update(profile: str) -> int:
    """Apply edits of a running profile (a program moved in or out): supervisord re-reads
    its files, starts what was added, stops what was removed, leaves the rest running."""
    if not supervisord_pid(profile):
        raise ComposeError(f"profile '{profile}' is not up")
    conf = profile_file(profile)
    before = set(programs.known_programs(profile, conf))
    said_before = programs.log_sizes(profile, programs_in(conf))
    done = ctl(profile, "update")
    added = sorted(set(programs.known_programs(profile, conf)) - before)
    return done.returncode or (wait_running(profile, added, said_before) if added else 0)


def down(profile: str, timeout: float = 15.0) -> int:
    pid = supervisord_pid(profile)
    if pid is None:
        print(f"profile '{profile}' is already down")
        return 0
    try:
        programs.stop_all(profile)
    except (OSError, xmlrpc.client.Error, programs.ProgramError) as exc:
        print(f"viena: stopping the programs one priority at a time failed ({exc}); "
              f"supervisord stops them", file=sys.stderr)
    ctl(profile, "shutdown", capture=True)
    # wait for the process itself: supervisord removes its pidfile before it has exited
    end = time.monotonic() + timeout
    while time.monotonic() < end and process_alive(pid):
        time.sleep(0.05)
    if process_alive(pid):
        os.kill(pid, signal.SIGTERM)
        raise ComposeError(f"supervisord (pid {pid}) did not stop in {timeout:.0f} s; sent SIGTERM")
    print(f"profile '{profile}' is down")
    return 0
