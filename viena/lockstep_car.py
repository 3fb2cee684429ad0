"""The sim profile's programs in one process, on a virtual clock: the car in lockstep.

`LockstepCar()` reads the same profile (compose/sim.conf and the program files it
includes) and the same settings (compose/sim.toml) as `viena up`, builds every program's
`Service` from its command line, and serves each on a session of an in-memory bus
(viena.common.lockstep.bus) instead of zenoh, on a `VirtualClock` instead of the wall's.
The device twins reach the unchanged drivers through in-memory serial links and a
lockstep CAN interface. Only the router is left out: the bus is the router.

    from viena.lockstep_car import LockstepCar
    with LockstepCar(seed=3) as car:
        car.run_for(60)                         # a minute of driving, in a second or two
        state = car.latest("estimator/state")   # the newest sample on a key, decoded

A program killed with `kill(name)` loses what SIGKILL loses (its threads never run again,
its session, tokens and serial ports go), and `start(name)` builds it anew from its
settings, as supervisord restarts it. The same seed and settings give the same bytes on
every key.
"""
from __future__ import annotations

import copy
import importlib
import logging
import re
import shlex
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from viena.common import clock
from viena.common.config import load_toml
from viena.common.keys import Keys
from viena.common.lockstep.bus import MemoryBus
from viena.common.lockstep.can import register as register_lockstep_can
from viena.common.lockstep.links import ports_of
from viena.common.lockstep.scheduler import VirtualClock
from viena.common.service import Service, build_parser
from viena.profile_security import profile_text

log = logging.getLogger(__name__)

PROFILES = Path(__file__).resolve().parent / "profiles"
SIM_CONF = PROFILES / "sim.conf"
SIM_TOML = PROFILES / "sim.toml"
#: how long a stopping program may take before the runner leaves it (virtual seconds)
STOP_WAIT_S = 3.0
#: supervisord's pause before it starts a program that died again (startretries' backoff)
RESTART_DELAY_S = 1.0

_PROGRAM = re.compile(r"^\[program:([^\]]+)\]\s*\ncommand\s*=\s*(.+)$", re.M)
#: a program `viena up` starts only when asked (autostart from the environment: the
#: corrections chain of `up --rtk`, whose caster is a TCP server the lockstep wire does not carry)
_OPTIONAL = re.compile(r"^autostart\s*=\s*%\(ENV_", re.M)


@dataclass(frozen=True)
class Program:
    """One program of a profile: its name, its service class and its own flags."""
    name: str
    service: type[Service]
    argv: tuple[str, ...]


def profile_programs(conf: Path = SIM_CONF) -> list[Program]:
    """The viena services a supervisord profile runs, in the order it lists them, read
    from each program's command line (`python -m MODULE FLAGS --config FILE`)."""
    programs = []
    text = profile_text(conf)
    for match in _PROGRAM.finditer(text):
        name, command = match.groups()
        block = text[match.end():].split("\n[", 1)[0]
        if _OPTIONAL.search(block):
            continue
        words = shlex.split(command)
        if "-m" not in words:
            continue
        module_name = words[words.index("-m") + 1]
        argv = words[words.index("-m") + 2:]
        if "--config" in argv:
            at = argv.index("--config")
            del argv[at:at + 2]
        service = _service_class(module_name)
        if service is not None:
            programs.append(Program(name, service, tuple(argv)))
    return programs


def _service_class(module_name: str) -> type[Service] | None:
    """The Service a module defines (None for the router and other non-services)."""
    module = importlib.import_module(module_name)
    for value in vars(module).values():
        if isinstance(value, type) and issubclass(value, Service) and value.__module__ == module_name:
            return value
    return None


def lockstep_settings(toml: dict) -> dict:
    """The profile's settings with every device on the lockstep wire: serial twins at
    `mem://NAME`, the steering drive on the `lockstep` CAN interface."""
    out = copy.deepcopy(toml)
    sim = out.setdefault("sim", {})
    sim["host"] = "mem"
    for name in sim.get("devices", []):
        kind = sim.get(name, {}).get("kind")
        if kind in ("novatel", "nmea"):
            out.setdefault("gnss", {}).setdefault(name, {})["port"] = f"mem://{name}"
        elif kind == "razor":
            out.setdefault("imu", {}).setdefault(name, {})["port"] = f"mem://{name}"
        elif kind == "epos":
            out.setdefault("steering", {}).update(interface="lockstep", channel=name)
    out.pop("zenoh", None)
    return out


def merge(base: dict, overrides: dict) -> dict:
    """`base` with `overrides` laid over it, table by table."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


class LockstepCar:
    """See the module docstring."""

    def __init__(self, settings: Path | dict = SIM_TOML, *, overrides: dict | None = None, seed: int | None = None,
                 programs: Iterable[str] | None = None, conf: Path = SIM_CONF, realtime: float | None = None,
                 watchdog_s: float = 120.0, cpu: int | str | None = None):
        toml = load_toml(settings) if isinstance(settings, Path) else settings
        toml = lockstep_settings(toml)
        if seed is not None:
            overrides = merge({"sim": {"seed": seed}}, overrides or {})
        self.settings = merge(toml, overrides or {})
        self.settings_source = settings if isinstance(settings, Path) else Path("<settings>")
        self.keys = Keys(self.settings.get("car", "elettra"))
        known = {p.name: p for p in profile_programs(conf)}
        wanted = list(known) if programs is None else list(programs)
        unknown = [name for name in wanted if name not in known]
        if unknown:
            raise ValueError(f"no program {', '.join(unknown)} in {conf.name} (have: {', '.join(known)})")
        self.programs = {name: known[name] for name in wanted}
        register_lockstep_can()
        # cpu: one CPU for every thread of the car ("auto": one no other simulation holds),
        # which halves the cost of a thread switch (common/lockstep/scheduler.py)
        self.clock = VirtualClock(realtime=realtime, watchdog_s=watchdog_s, seed=seed or 0, cpu=cpu)
        self.bus = MemoryBus()
        self.services: dict[str, Service] = {}
        self._threads: dict[str, Any] = {}
        self._sessions: dict[str, Any] = {}
        self._started = False
        self._observer: Any = None
        self._tool_sessions: dict[str, list[Any]] = {}

    # -- life ------------------------------------------------------------------------------------
    def __enter__(self) -> LockstepCar:
        self.start_all()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start_all(self) -> None:
        """Enter the virtual clock (this thread drives it) and start every program."""
        if not self._started:
            self.clock.enter()
            self._started = True
        for name in self.programs:
            self.start(name)

    def start(self, name: str) -> Service:
        """Build program `name` from its settings and serve it, as supervisord starts it."""
        program = self.programs[name]
        args = build_parser(program.service).parse_args(list(program.argv))
        args.config = self.settings_source
        args.settings = self.settings
        with self.clock.group(name):
            service = program.service(args)
            session = self.bus.session(name)
            thread = clock.Thread(service.serve, name=name, args=(session,))
            thread.start()
        self.services[name], self._threads[name], self._sessions[name] = service, thread, session
        return service

    def stop(self, name: str) -> None:
        """SIGTERM: the program stops as it would (its `stop()`, its session closed)."""
        service = self.services.pop(name)
        service.stopping.set()
        self._threads.pop(name).join(STOP_WAIT_S)
        self._sessions.pop(name, None)

    def kill(self, name: str) -> None:
        """SIGKILL: the program's threads never run again; its session and tokens vanish
        (the bus's view of a dead peer), its serial ports and CAN adapter are unplugged.
        `name` may also be a tool's: the sessions made by `session(name)` and the threads
        started inside `clock.group(name)`."""
        self.clock.kill(name)
        self.services.pop(name, None)
        self._threads.pop(name, None)
        for session in [self._sessions.pop(name, None), *self._tool_sessions.pop(name, [])]:
            if session is not None:
                session.kill()
        if name in self.programs:
            self._unplug(name)

    def restart(self, name: str, delay_s: float = RESTART_DELAY_S) -> Service:
        """Kill, wait as supervisord would, start again."""
        self.kill(name)
        self.run_for(delay_s)
        return self.start(name)

    def close(self) -> None:
        """Stop every program (SIGTERM, in reverse order), then end the simulation."""
        if not self._started:
            return
        try:
            for name in reversed(list(self.services)):
                try:
                    self.stop(name)
                except Exception:
                    log.exception("stopping %s", name)
        finally:
            self.clock.close()
            self._started = False

    def _unplug(self, name: str) -> None:
        """A killed device service lets go of its serial line, as the kernel closes a dead
        process's port; a killed sim takes its twins with it."""
        ports = ports_of()
        program = self.programs[name]
        if program.service.name == "sim":
            for device in ports.names():
                ports.endpoint(device).stop()
            return
        unit = _flag(program.argv, "--unit")
        if unit in ports.names():
            ports.endpoint(unit).hang_up()

    # -- watching ----------------------------------------------------------------------------
    def session(self, name: str = "observer") -> Any:
        """A session on the car's bus for a test or a tool (a person's laptop); `kill(name)`
        kills it with the threads started inside `clock.group(name)`, as SIGKILL kills a
        process."""
        session = self.bus.session(name)
        self._tool_sessions.setdefault(name, []).append(session)
        return session

    def collect(self, keyexpr: str, decode: Callable[[bytes], Any] | None = None) -> list:
        """A list that fills with every sample on `keyexpr` from now on: decoded by
        `decode`, else as (key, payload bytes)."""
        if self._observer is None:
            self._observer = self.session("observer")
        got: list = []
        if decode is None:
            self._observer.declare_subscriber(
                keyexpr, lambda s: got.append((str(s.key_expr), s.payload.to_bytes())))
        else:
            self._observer.declare_subscriber(keyexpr, lambda s: got.append(decode(s.payload.to_bytes())))
        return got

    def run_for(self, seconds: float) -> None:
        self.clock.run_for(seconds)

    def run_to(self, time_ns: int) -> None:
        """Run until the virtual Unix time is exactly `time_ns` (e.g. a recording's log time)."""
        self.clock.run_for_ns(time_ns - self.clock.time_ns())

    def run_until(self, condition: Callable[[], bool], within_s: float, step_s: float = 0.05) -> bool:
        return self.clock.run_until(condition, within_s, step_s)

    @property
    def now_s(self) -> float:
        return self.clock.monotonic_ns() / 1e9

    def key(self, *parts: str) -> str:
        return self.keys.key(*parts)


def _flag(argv: tuple[str, ...], flag: str) -> str | None:
    return argv[argv.index(flag) + 1] if flag in argv[:-1] else None
