"""Scenario files for `viena sim run`: a drive in virtual time, described in TOML.

A scenario is the sim profile's settings (compose/sim.toml) with some tables overridden,
a route, a length, and a timeline of events (docs/simulation.md#scenario-files):

    description = "both receivers lose the sky for 10 s"
    duration_s = 150
    route = "loop"                     # the sim's loop from where the car is, or a route file

    [sim.gnss0]                        # any table of compose/sim.toml, merged over it
    cep_m = 0.05

    [[events]]
    at_s = 40
    gnss_outage = ["gnss0", "gnss1"]
    for_s = 10

Everything is checked when the file is read, with the services' own settings checks, and
a mistake is one line naming the file and the field: `kills.toml: events[2].kill: no
program 'gnss3' (have: sim, gnss0, ...)`.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from viena.common.config import load_toml, merge_settings
from viena.common.errors import ConfigError
from viena.lockstep_car import PROFILES, SIM_TOML, Program, lockstep_settings, merge, profile_programs

SCENARIOS = PROFILES / "scenarios"
DEFAULT = SCENARIOS / "loop.toml"
#: the scenario's own top-level names; every other top-level table overrides sim.toml's
OWN = ("description", "duration_s", "route", "events")
#: the tables of sim.toml a scenario may override
SECTIONS = ("car", "sim", "gnss", "imu", "steering", "estimator", "pilot")
DEFAULT_DURATION_S = 120.0
LOOP = "loop"


class ScenarioError(ConfigError):
    """A scenario that cannot be run; its message is one line naming the file and field."""


@dataclass(frozen=True)
class Event:
    """One thing that happens at `at_s` (virtual seconds since the drive began).

    kind: kill | stop | start (a program), gnss_outage (receivers), imu_bias (an IMU twin),
    steering_fault (the drive), flood (a key); `target` names what it acts on, `options`
    holds the rest of its table (for_s, gyro_dps, code, rate_hz ...)."""

    at_s: float
    kind: str
    target: Any
    options: dict = field(default_factory=dict)

    def describe(self) -> str:
        o = self.options
        if self.kind == "kill":
            back = o["restart_after_s"]
            return f"kill {self.target}" + ("" if back < 0 else f", restarted {back:g} s later")
        if self.kind in ("stop", "start"):
            return f"{self.kind} {self.target}"
        if self.kind == "gnss_outage":
            return f"GNSS outage on {', '.join(self.target)} for {o['for_s']:g} s"
        if self.kind == "imu_bias":
            parts = [f"{name} {list(o[name])}" for name in ("gyro_dps", "accel_mg") if name in o]
            return f"bias step on {self.target}: {', '.join(parts)}"
        if self.kind == "steering_fault":
            return f"EPOS error 0x{o['code']:04X} on {self.target}"
        return f"flood on {self.target}: {o['rate_hz']:g}/s for {o['for_s']:g} s, {o['bytes']} bytes each"


@dataclass(frozen=True)
class Scenario:
    """A parsed, checked scenario file."""

    path: Path
    description: str
    duration_s: float
    route: Path | None                  # None: the sim's loop from where the car is
    overrides: dict                     # merged over compose/sim.toml by LockstepCar
    events: tuple[Event, ...]

    @property
    def name(self) -> str:
        return self.path.stem


def resolve(name: str | None) -> Path:
    """A scenario argument as a file: a path, or the name of a shipped one ("gnss_outage")."""
    if name is None:
        return DEFAULT
    path = Path(name)
    if path.suffix != ".toml" and not path.exists() and (SCENARIOS / f"{name}.toml").exists():
        return SCENARIOS / f"{name}.toml"
    return path


def shipped() -> list[str]:
    return sorted(p.stem for p in SCENARIOS.glob("*.toml"))


def load(path: str | Path) -> Scenario:
    """Read and check a scenario file; ScenarioError (one line) if anything is wrong."""
    path = Path(path)
    if not path.exists():
        raise ScenarioError(f"{path}: no such file (shipped scenarios: {', '.join(shipped())})")
    try:
        raw = load_toml(path)
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from None
    return parse(raw, path)


def parse(raw: dict, path: Path) -> Scenario:
    """A Scenario from a TOML document already read (see `load`)."""
    where = _Where(path)
    overrides = {}
    for key, value in raw.items():
        if key in OWN:
            continue
        if key not in SECTIONS:
            raise where.error(key, f"unknown name (a scenario has {', '.join(OWN)} and tables of sim.toml: "
                                   f"{', '.join(SECTIONS)})")
        if key == "car" and not isinstance(value, str):
            raise where.error(key, f"must be the car's name, got {value!r}")
        if key != "car" and not isinstance(value, dict):
            raise where.error(key, "must be a table")
        overrides[key] = value
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise where.error("description", "must be text")
    duration = _number(raw.get("duration_s", DEFAULT_DURATION_S), where, "duration_s", positive=True)
    route = _route(raw.get("route", LOOP), where)
    settings = merge(lockstep_settings(_base()), overrides)
    programs = {p.name: p for p in profile_programs()}
    _check_settings(settings, programs, path)
    events = raw.get("events", [])
    if not isinstance(events, list):
        raise where.error("events", "must be an array of tables ([[events]])")
    checked = tuple(_event(e, where.at(f"events[{i}]"), settings, programs) for i, e in enumerate(events))
    return Scenario(path, description, duration, route, overrides,
                    tuple(sorted(checked, key=lambda e: e.at_s)))


# -- the parts -------------------------------------------------------------------------------------
class _Where:
    """Names the file and the field a problem is in."""

    def __init__(self, path: Path, prefix: str = ""):
        self.path, self.prefix = path, prefix

    def at(self, prefix: str) -> _Where:
        return _Where(self.path, prefix)

    def error(self, name: str, problem: str) -> ScenarioError:
        field_name = ".".join(part for part in (self.prefix, name) if part)
        return ScenarioError(f"{self.path}: {field_name}: {problem}")


def _base() -> dict:
    return load_toml(SIM_TOML)


def _number(value: Any, where: _Where, name: str, positive: bool = False, at_least: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise where.error(name, f"must be a number, got {value!r}")
    if positive and value <= 0:
        raise where.error(name, f"must be more than 0, got {value!r}")
    if at_least is not None and value < at_least:
        raise where.error(name, f"must be at least {at_least:g}, got {value!r}")
    return float(value)


def _vector(value: Any, where: _Where, name: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise where.error(name, f"must be 3 numbers [x, y, z], got {value!r}")
    x, y, z = (_number(v, where, name) for v in value)
    return x, y, z


def _route(value: Any, where: _Where) -> Path | None:
    """"loop", or a route file (GeoJSON, point list, CSV: anything `viena route send` takes),
    relative to the scenario file, read and checked now with the pilot's own parser."""
    if not isinstance(value, str) or not value:
        raise where.error("route", f'must be "loop" or a route file, got {value!r}')
    if value == LOOP:
        return None
    try:
        return route_file(where.path.parent / value)
    except ScenarioError as exc:
        raise where.error("route", str(exc)) from None


def route_file(path: Path) -> Path:
    """A route file, read and checked with the pilot's own parser (ScenarioError if not)."""
    from viena.services.pilot.model.route import RouteError, parse_route
    try:
        parse_route(Path(path).read_bytes())
    except OSError as exc:
        raise ScenarioError(f"cannot read {path}: {exc.strerror}") from None
    except RouteError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    return Path(path).resolve()


def _check_settings(settings: dict, programs: dict[str, Program], path: Path) -> None:
    """Every program's settings as it would read them at start (its own checks), and the
    device twins' tables, so a typo is found before the car starts."""
    from viena.common.service import build_parser

    try:
        for program in programs.values():
            args = build_parser(program.service).parse_args(list(program.argv))
            args.config = path
            program.service.read_settings(settings, getattr(args, "unit", None) or program.service.default_unit,
                                          args)
        sim = settings.get("sim", {})
        for name in sim.get("devices", []):
            table = dict(sim.get(name, {}))
            kind = table.pop("kind", None)
            check = _DEVICE_CHECKS.get(kind)
            if check is not None:
                check(table, f"{path} [sim.{name}]")
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from None


def _serial_twin(module: str) -> Callable[[dict, str], None]:
    def check(table: dict, source: str) -> None:
        import importlib
        merge_settings(importlib.import_module(module).TWIN_SETTINGS, table, source)
    return check


def _epos_twin(table: dict, source: str) -> None:
    from dataclasses import fields

    from viena.services.steering.simulator import PLANTS, TwinSettings
    known = {f.name for f in fields(TwinSettings)} - {"plant"} | {"port", "bitrate", "plant"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{source}: unknown setting '{unknown[0]}' (known: {', '.join(sorted(known))})")
    if table.get("plant", "traj01") not in PLANTS:
        raise ConfigError(f"{source}: plant must be one of {sorted(PLANTS)}, got {table['plant']!r}")


_DEVICE_CHECKS = {"novatel": _serial_twin("viena.services.gnss.simulator"),
                  "nmea": _serial_twin("viena.services.gnss.simulator"),
                  "razor": _serial_twin("viena.services.imu.simulator"),
                  "epos": _epos_twin}

#: event kind -> (the options it takes with their defaults; None: required)
KINDS: dict[str, dict[str, Any]] = {
    "kill": {"restart_after_s": 1.0},
    "stop": {},
    "start": {},
    "gnss_outage": {"for_s": None},
    "imu_bias": {"gyro_dps": (0.0, 0.0, 0.0), "accel_mg": (0.0, 0.0, 0.0)},
    "steering_fault": {"device": ""},
    "flood": {"rate_hz": None, "for_s": None, "bytes": 64, "payload": ""},
}


def _event(table: Any, where: _Where, settings: dict, programs: dict[str, Program]) -> Event:
    if not isinstance(table, dict):
        raise where.error("", "must be a table")
    if "at_s" not in table:
        raise where.error("at_s", "missing: when it happens, in seconds since the drive began")
    at_s = _number(table["at_s"], where, "at_s", at_least=0.0)
    kinds = [k for k in table if k in KINDS]
    if len(kinds) != 1:
        raise where.error("", f"needs exactly one of {', '.join(KINDS)}, got {', '.join(kinds) or 'none'}")
    kind = kinds[0]
    allowed = KINDS[kind]
    for name in table:
        if name not in (*allowed, "at_s", kind):
            raise where.error(name, f"not an option of {kind} (it takes {', '.join(allowed) or 'none'})")
    for name, default in allowed.items():
        if default is None and name not in table:
            raise where.error(name, f"missing: {kind} needs it")
    options = {name: table.get(name, default) for name, default in allowed.items()}
    target = _TARGETS[kind](table[kind], where, kind, settings, programs, options)
    return Event(at_s, kind, target, options)


def _program(value: Any, where: _Where, kind: str, settings: dict, programs: dict, options: dict) -> str:
    if value not in programs:
        raise where.error(kind, f"no program {value!r} (have: {', '.join(programs)})")
    if kind == "kill":
        options["restart_after_s"] = _number(options["restart_after_s"], where, "restart_after_s")
    return value


def _devices_of(settings: dict, kinds: tuple[str, ...]) -> list[str]:
    sim = settings.get("sim", {})
    return [n for n in sim.get("devices", []) if sim.get(n, {}).get("kind") in kinds]


def _receivers(value: Any, where: _Where, kind: str, settings: dict, programs: dict, options: dict) -> tuple:
    have = _devices_of(settings, ("novatel", "nmea"))
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise where.error(kind, f"must be a receiver or a list of them, got {value!r}")
    for name in names:
        if name not in have:
            raise where.error(kind, f"no GNSS receiver {name!r} in [sim] devices (have: {', '.join(have)})")
    options["for_s"] = _number(options["for_s"], where, "for_s", positive=True)
    return tuple(names)


def _imu(value: Any, where: _Where, kind: str, settings: dict, programs: dict, options: dict) -> str:
    have = _devices_of(settings, ("razor",))
    if value not in have:
        raise where.error(kind, f"no IMU twin {value!r} in [sim] devices (have: {', '.join(have)})")
    options["gyro_dps"] = _vector(list(options["gyro_dps"]), where, "gyro_dps")
    options["accel_mg"] = _vector(list(options["accel_mg"]), where, "accel_mg")
    return value


def _steering(value: Any, where: _Where, kind: str, settings: dict, programs: dict, options: dict) -> str:
    from viena.services.steering.driver.emcy import EPOS_ERRORS
    if isinstance(value, bool) or not isinstance(value, int) or value not in EPOS_ERRORS or value == 0:
        known = ", ".join(f"0x{c:04X}" for c in EPOS_ERRORS if c)
        raise where.error(kind, f"must be an EPOS error code (0x4210 is Over Temperature; known: {known}), "
                                f"got {value!r}")
    have = _devices_of(settings, ("epos",))
    device = options.pop("device") or (have[0] if have else "")
    if device not in have:
        raise where.error("device", f"no EPOS twin {device!r} in [sim] devices (have: {', '.join(have) or 'none'})")
    options["code"] = value
    return device


def _flood(value: Any, where: _Where, kind: str, settings: dict, programs: dict, options: dict) -> str:
    if not isinstance(value, str) or not value or value.startswith("/"):
        raise where.error(kind, f"must be a key below viena/<car>/ (\"pilot/route\"), got {value!r}")
    options["rate_hz"] = _number(options["rate_hz"], where, "rate_hz", positive=True)
    options["for_s"] = _number(options["for_s"], where, "for_s", positive=True)
    if isinstance(options["bytes"], bool) or not isinstance(options["bytes"], int) or options["bytes"] < 0:
        raise where.error("bytes", f"must be a whole number of bytes, got {options['bytes']!r}")
    if not isinstance(options["payload"], str):
        raise where.error("payload", f"must be text, got {options['payload']!r}")
    if options["payload"]:
        options["bytes"] = len(options["payload"].encode())
    return value


_TARGETS: dict[str, Callable[..., Any]] = {
    "kill": _program, "stop": _program, "start": _program, "gnss_outage": _receivers,
    "imu_bias": _imu, "steering_fault": _steering, "flood": _flood,
}


def describe(scenario: Scenario) -> str:
    """A few lines saying what the scenario does (for --help-like listings)."""
    lines = [f"{scenario.name}: {scenario.description or '(no description)'}"]
    lines += [f"  at {e.at_s:g} s: {e.describe()}" for e in scenario.events]
    return "\n".join(lines)


