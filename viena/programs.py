"""The programs of a running profile, one at a time: are they really up, their logs, and
restarting or stopping one (`viena logs|restart|stop|start NAME`).

supervisord is asked over its XML-RPC socket (`<run>/supervisor.sock`), so states,
start times and exit statuses come as data, not as text to parse. "Up" means more than
supervisord's RUNNING, which a program reaches once it has lived `startsecs`: on a busy
machine a program still importing its modules is RUNNING, and one that then stops at a bad
setting is restarted and RUNNING again at the next look. So `wait_settled` waits until
each program has said something (its first log line: a service says `started`, the router
`listening`, a bad setting its one line) and has stayed in the same run SETTLE_S after
that (a program that says nothing: QUIET_S after RUNNING), and reports any that exited,
backed off or was restarted meanwhile, with the last lines of its log.
"""
from __future__ import annotations

import sys
import time
import xmlrpc.client
from dataclasses import dataclass
from pathlib import Path

from viena.common.runstate import run_dir
from viena.profile_security import programs as programs_in

#: how long a program must stay in one run after its first word (and RUNNING)
SETTLE_S = 2.0
#: ... or after RUNNING, if it writes nothing to its log. Every program of viena's profiles
#: speaks first, so this is for others; it is long because a program still importing its
#: modules says nothing yet: on a busy 2-core machine the estimator took 14.7 s to reach
#: its bad setting and exit (a 10 s wait had called it up)
QUIET_S = 30.0
SETTLE_TIMEOUT_S = 60.0
LOG_LINES = 8
FOLLOW_PERIOD_S = 0.2
FAILED = ("BACKOFF", "EXITED", "FATAL", "UNKNOWN")
#: states in which a program still has a process
ALIVE = ("STARTING", "RUNNING", "STOPPING")
#: `viena down` stops the programs itself for this long, then leaves the rest to supervisord
STOP_ALL_TIMEOUT_S = 10.0


class ProgramError(Exception):
    """Something a person can fix: said in one line (or a few, for failed programs)."""


def rpc(profile: str):
    """supervisord's XML-RPC interface for a running profile."""
    from supervisor.xmlrpc import SupervisorTransport

    sock = run_dir(profile) / "supervisor.sock"
    transport = SupervisorTransport(None, None, f"unix://{sock}")
    return xmlrpc.client.ServerProxy("http://127.0.0.1", transport=transport).supervisor


def known_programs(profile: str, conf: Path) -> list[str]:
    """The profile's program names: supervisord's if it runs, else its files'."""
    try:
        return sorted(info["name"] for info in rpc(profile).getAllProcessInfo())
    except (OSError, xmlrpc.client.Error):
        return sorted(programs_in(conf))


def check_name(profile: str, conf: Path, name: str) -> None:
    known = known_programs(profile, conf)
    if name not in known:
        raise ProgramError(f"no program '{name}' in profile {profile} (have: {', '.join(known)})")


def log_path(profile: str, name: str) -> Path:
    return run_dir(profile) / f"{name}.log"


def last_lines(path: Path, n: int = LOG_LINES) -> list[str]:
    """The last `n` lines of a log (at most its last 64 kB are read)."""
    try:
        with path.open("rb") as f:
            f.seek(0, 2)
            size = f.tell()
            f.seek(max(0, size - 65536))
            text = f.read().decode(errors="replace")
    except OSError:
        return []
    return [line for line in text.splitlines() if line.strip()][-n:]


@dataclass
class Failure:
    name: str
    state: str
    exitstatus: int | None
    lines: list[str]

    def describe(self) -> str:
        status = f", exit status {self.exitstatus}" if self.exitstatus not in (None, 0) else ""
        head = f"  {self.name}: {self.state}{status}; its log ends:"
        return "\n".join([head, *(f"    {line}" for line in self.lines or ["(empty)"])])


def log_sizes(profile: str, names: list[str]) -> dict[str, int]:
    """The size of each program's log now: what it says after this is new."""
    return {name: _size(log_path(profile, name)) for name in names}


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def wait_settled(profile: str, names: list[str] | None = None, said_before: dict[str, int] | None = None,
                 timeout: float = SETTLE_TIMEOUT_S) -> list[Failure]:
    """Until every program (or those in `names`) has stayed RUNNING in one run for SETTLE_S
    past its first new log line (`said_before`: the log sizes before it started; default:
    now); the programs that failed meanwhile (empty when all are up). A program not up
    after `timeout` counts as failed."""
    supervisor = rpc(profile)
    if names is None:       # a program left off (autostart false: `up` without --rtk) is not waited for
        names = [c["name"] for c in supervisor.getAllConfigInfo() if c.get("autostart", True)]
    end = time.monotonic() + timeout
    said_before = dict(said_before or {})
    runs: dict[str, tuple[int, float]] = {}      # name -> (start time of its run, seen RUNNING at)
    spoke: dict[str, float] = {}                 # name -> when its log first grew
    failed: dict[str, tuple[str, int | None]] = {}      # name -> (what, exit status then)

    def settled(name: str, now: float) -> bool:
        if name not in runs:
            return False
        since = max(spoke[name], runs[name][1]) if name in spoke else None
        return (since is not None and now - since >= SETTLE_S) or now - runs[name][1] >= QUIET_S

    while True:
        now = time.monotonic()
        infos = [i for i in supervisor.getAllProcessInfo() if names is None or i["name"] in names]
        for info in infos:
            name, state = info["name"], info["statename"]
            if name in failed:
                continue
            said_before.setdefault(name, _size(log_path(profile, name)))
            if name not in spoke and _size(log_path(profile, name)) > said_before[name]:
                spoke[name] = now
            if state in FAILED:
                failed[name] = (state, info["exitstatus"])
            elif state == "RUNNING":
                first = runs.get(name)
                if first is None:
                    runs[name] = (info["start"], now)
                elif first[0] != info["start"]:
                    failed[name] = ("restarted (it exited and supervisord started it again)", None)
            elif name in runs:                          # left RUNNING: stopping, starting again
                failed[name] = (state, None)
            # STOPPED or STARTING before its first RUNNING: not started yet, wait
        if all(i["name"] in failed or settled(i["name"], now) for i in infos) or now > end:
            break
        time.sleep(0.1)
    for info in infos:
        if info["name"] not in failed and not settled(info["name"], now):
            failed[info["name"]] = (f"{info['statename']}, not settled after {timeout:.0f} s", None)
    return [Failure(name, state, status, last_lines(log_path(profile, name)))
            for name, (state, status) in sorted(failed.items())]


def report(profile: str, failures: list[Failure]) -> int:
    """Say which programs are not up and why; the exit status of the command."""
    if not failures:
        return 0
    print(f"viena: {len(failures)} program(s) of profile {profile} not up:", file=sys.stderr)
    for failure in failures:
        print(failure.describe(), file=sys.stderr)
    print(f"(the rest keeps running: fix the cause, then `viena restart NAME`, or `viena down "
          f"--profile {profile}`)", file=sys.stderr)
    return 1


def restart(profile: str, conf: Path, name: str) -> int:
    check_name(profile, conf, name)
    supervisor = rpc(profile)
    _stop(supervisor, name)
    return start(profile, conf, name)


def start(profile: str, conf: Path, name: str) -> int:
    check_name(profile, conf, name)
    before = log_sizes(profile, [name])
    try:
        rpc(profile).startProcess(name, False)
    except xmlrpc.client.Fault as exc:
        if "ALREADY_STARTED" not in exc.faultString:
            raise ProgramError(f"{name}: {exc.faultString}") from None
        print(f"{name}: already running (`viena restart {name}` restarts it)")
        return 0
    status = report(profile, wait_settled(profile, [name], before))
    if status == 0:
        print(f"{name}: running")
    return status


def stop(profile: str, conf: Path, name: str) -> int:
    check_name(profile, conf, name)
    _stop(rpc(profile), name)
    print(f"{name}: stopped (`viena start {name}` starts it again)")
    return 0


def _stop(supervisor, name: str, wait: bool = True) -> None:
    try:
        supervisor.stopProcess(name, wait)
    except xmlrpc.client.Fault as exc:
        if "NOT_RUNNING" not in exc.faultString:
            raise ProgramError(f"{name}: {exc.faultString}") from None


def stop_all(profile: str, timeout: float = STOP_ALL_TIMEOUT_S) -> None:
    """Stop every program in supervisord's order (the highest priority number first: the
    pilot, then the services, then the sim, the router last), but the programs of one
    priority at once. supervisord's own shutdown stops one program at a time and notices
    each exit only at its next tick of up to a second: eight programs took 8-9 s."""
    supervisor = rpc(profile)
    bands: dict[int, list[str]] = {}
    for info in supervisor.getAllConfigInfo():
        bands.setdefault(info["process_prio"], []).append(f"{info['group']}:{info['name']}")
    end = time.monotonic() + timeout
    for priority in sorted(bands, reverse=True):
        for name in bands[priority]:
            _stop(supervisor, name, wait=False)
        while any(f"{info['group']}:{info['name']}" in bands[priority] and info["statename"] in ALIVE
                  for info in supervisor.getAllProcessInfo()):            # one call a poll
            if time.monotonic() > end:
                return                  # supervisord's shutdown goes on from here, and kills
            time.sleep(0.05)


def logs(profile: str, conf: Path, name: str, follow: bool = False, lines: int = 200) -> int:
    """The end of a program's log; with `follow`, what it writes next, until Ctrl-C."""
    check_name(profile, conf, name)
    path = log_path(profile, name)
    if not path.exists() and not follow:
        raise ProgramError(f"no log for '{name}' yet in {path.parent}")
    for line in last_lines(path, lines):
        print(line)
    if follow:
        _follow(path)
    return 0


def _follow(path: Path) -> None:
    """Print what is appended to `path`; a log rotated by supervisord is reopened."""
    offset = path.stat().st_size if path.exists() else 0
    try:
        while True:
            try:
                size = path.stat().st_size
            except FileNotFoundError:
                size = 0
            if size < offset:                   # rotated: start from the new file's beginning
                offset = 0
            if size > offset:
                with path.open("rb") as f:
                    f.seek(offset)
                    chunk = f.read(size - offset)
                offset += len(chunk)
                sys.stdout.write(chunk.decode(errors="replace"))
                sys.stdout.flush()
            time.sleep(FOLLOW_PERIOD_S)
    except KeyboardInterrupt:
        pass
