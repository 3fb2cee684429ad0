"""Settings: one dataclass per service, each setting declared once; its defaults, the TOML
table, the command-line flags and the README's table all come from that declaration.

    @dataclass(frozen=True)
    class ImuSettings:
        port: str = setting("", "the unit's serial port as a pyserial URL", metavar="URL")
        stall_s: float = setting(10.0, "no frame for this long on an open port: reopen it")

The annotation is the setting's type: `bool`, `int`, `float`, `str`, `tuple[T, ...]` (a
TOML list), `dict[str, T]` (a TOML table) or `Any`. The unit goes in the name, the help is
one line. A field declared with `part()` holds another settings dataclass (steering's
drive, envelope, calibration, controller): its settings sit beside the service's own, so
a TOML table and the command line name every setting the same flat way, and names are
unique within a service.

What comes from the class:
- `load(cls, layers)`: settings from mappings (the TOML tables, then the flags), each later
  one winning; an unknown name or a wrong type is a ConfigError of one line naming the
  source and the setting (`${VAR}` was already expanded by common/config.py, so numbers
  and booleans may arrive as text);
- `add_flags(parser, cls)` and `given_flags(args, cls)`: `--name-with-dashes` per setting;
- `markdown(cls)` and `toml_table(cls, name)`: the table (setting, type, default, what)
  for the READMEs, and the defaults as TOML, both printed by `viena settings`.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

from viena.common.errors import ConfigError

_SCALARS = (bool, int, float, str)
_METAVARS = {int: "INT", float: "NUMBER", str: "TEXT"}


def setting(default: Any, help: str, *, choices: Iterable | None = None,
            metavar: str | tuple[str, ...] | None = None, flags: tuple[str, ...] = (),
            shown: str | None = None) -> Any:
    """A settings field: its default and one line of help; optionally the values it may
    take (each element's, for a list), the flag's metavar (a tuple fixes a list's length),
    more flag names it answers to, and how to show a default that depends on the machine."""
    meta = {"help": help, "choices": None if choices is None else tuple(choices),
            "metavar": metavar, "flags": tuple(flags), "shown": shown}
    if isinstance(default, list):
        default = tuple(default)
    if isinstance(default, dict):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def part(cls: type, help: str) -> Any:
    """A field holding a part's settings dataclass, with one line saying what the part is."""
    return dataclasses.field(default_factory=cls, metadata={"help": help, "part": True})


@dataclass(frozen=True)
class Setting:
    """One setting as declared: where it sits (`part`, "" for the service's own)."""
    name: str
    type: Any
    default: Any
    help: str
    part: str
    choices: tuple | None = None
    metavar: str | tuple[str, ...] | None = None
    flags: tuple[str, ...] = ()
    shown: str | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def default_text(self) -> str:
        """The default as shown to people (help, README)."""
        return self.shown or toml_literal(self.default, digits=10)

    def check(self, value: Any, source: str) -> Any:
        """The value as its type (an int where a float is wanted becomes a float), or a
        ConfigError naming source and setting."""
        typed = convert(value, self.type, self.name, source)
        items = typed if isinstance(typed, tuple) else (typed,)
        if self.choices is not None and any(v not in self.choices for v in items):
            allowed = ", ".join(toml_literal(c) for c in self.choices)
            what = "hold only" if isinstance(typed, tuple) else "be one of"
            raise ConfigError(f"{source}: setting '{self.name}' must {what} {allowed}, got {value!r}")
        return typed


# -- the declaration ---------------------------------------------------------------------------
@cache
def specs(cls: type) -> dict[str, Setting]:
    """Every setting of `cls` and its parts, by name, in declaration order."""
    found: dict[str, Setting] = {}
    for f, tp in _fields(cls):
        if f.metadata.get("part"):
            inner = [dataclasses.replace(s, part=s.part or f.name) for s in specs(tp).values()]
        elif "help" in f.metadata:
            _type_name(tp)                                      # refuse types we cannot parse
            default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
            m = f.metadata
            inner = [Setting(f.name, tp, default, m["help"], "", m["choices"], m["metavar"],
                             m["flags"], m["shown"])]
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: declare it with setting() or part()")
        for s in inner:
            if s.name in found:
                raise TypeError(f"{cls.__name__}: two settings named '{s.name}'")
            found[s.name] = s
    return found


def parts(cls: type) -> dict[str, str]:
    """The parts of `cls`, by field name, with their help: what they are."""
    return {f.name: f.metadata["help"] for f, _ in _fields(cls) if f.metadata.get("part")}


def _fields(cls: type) -> list[tuple[dataclasses.Field, Any]]:
    hints = typing.get_type_hints(cls)
    return [(f, hints[f.name]) for f in dataclasses.fields(cls) if f.init]


# -- values ----------------------------------------------------------------------------------
def load(cls: type, layers: Iterable[tuple[Mapping, str]]):
    """An instance of `cls` from its defaults overlaid with each (mapping, source) in turn."""
    known = specs(cls)
    values: dict[str, Any] = {}
    for given, source in layers:
        for name, value in given.items():
            if name not in known:
                names = ", ".join(sorted(known)) or "none"
                raise ConfigError(f"{source}: unknown setting '{name}' (known: {names})")
            values[name] = known[name].check(value, source)
    return _build(cls, values)


def from_mapping(cls: type, given: Mapping | None, source: str):
    """An instance of `cls` from one mapping (a program's dict, a TOML table)."""
    return load(cls, [(given or {}, source)])


def _build(cls: type, values: dict[str, Any]):
    kwargs = {}
    for f, tp in _fields(cls):
        if f.metadata.get("part"):
            kwargs[f.name] = _build(tp, values)
        elif f.name in values:
            kwargs[f.name] = values[f.name]
    return cls(**kwargs)


class _Wrong(Exception):
    pass


def convert(value: Any, tp: Any, name: str, source: str) -> Any:
    """`value` as type `tp`, or a ConfigError: "<source>: setting 'name' must be float"."""
    try:
        return _convert(value, tp)
    except _Wrong:
        raise ConfigError(f"{source}: setting '{name}' must be {_type_name(tp)}, got {value!r}") from None


def _convert(value: Any, tp: Any) -> Any:
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false"):     # from ${VAR}
            return value.lower() == "true"
    elif tp in (int, float):
        number = isinstance(value, int) and not isinstance(value, bool)
        if number or (tp is float and type(value) is float):
            return tp(value)
        if isinstance(value, str):                                            # from ${VAR}
            try:
                return tp(value)
            except ValueError:
                pass
    elif tp is str:
        if isinstance(value, str):
            return value
    elif tp is list or typing.get_origin(tp) is tuple:
        if isinstance(value, (list, tuple)):
            items = [_convert(v, _item_type(tp)) for v in value]
            return items if tp is list else tuple(items)
    elif tp is dict or typing.get_origin(tp) is dict:
        if isinstance(value, dict):
            return {k: _convert(v, _item_type(tp)) for k, v in value.items()}
    raise _Wrong


def _item_type(tp: Any) -> Any:
    """What a list or table holds: T of tuple[T, ...] and of dict[str, T]; else Any."""
    args = typing.get_args(tp)
    return args[-1] if typing.get_origin(tp) is dict else (args[0] if args else Any)


def _type_name(tp: Any) -> str:
    if tp is Any:
        return "any"
    if tp in _SCALARS:
        return tp.__name__
    if tp is list or (typing.get_origin(tp) is tuple and typing.get_args(tp)[1:] == (...,)):
        return "list" if tp is list else f"list of {_type_name(_item_type(tp))}"
    if tp is dict or (typing.get_origin(tp) is dict and typing.get_args(tp)[0] is str):
        return "table" if tp is dict else f"table of {_type_name(_item_type(tp))}"
    raise TypeError(f"settings cannot hold {tp!r}: use bool, int, float, str, tuple[T, ...], "
                    f"dict[str, T] or Any")


def toml_literal(value: Any, digits: int | None = None) -> str:
    """A value as it is written in a TOML file; floats to `digits` significant digits if
    given (0.5061454831 reads better than 0.5061454830783556)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_literal(v, digits) for v in value) + "]"
    if isinstance(value, dict):
        pairs = (f"{json.dumps(k)} = {toml_literal(v, digits)}" for k, v in value.items())
        return "{" + ", ".join(pairs) + "}"
    if isinstance(value, float) and digits is not None:
        return repr(float(f"{value:.{digits}g}"))
    return repr(value)


# -- flags ---------------------------------------------------------------------------------------
def add_flags(parser: argparse.ArgumentParser, cls: type, title: str) -> None:
    """One flag per setting, grouped by part; a flag left out leaves the setting alone."""
    groups = {"": parser.add_argument_group(title)}
    for name, help in parts(cls).items():
        groups[name] = parser.add_argument_group(f"{name}: {help}")
    for s in specs(cls).values():
        group = groups.get(s.part) or groups.setdefault(s.part, parser.add_argument_group(s.part))
        text = f"{s.help} (default {s.default_text})".replace("%", "%%")
        group.add_argument(s.flag, *s.flags, dest=s.name, default=None, help=text, **_flag_kind(s))


def _flag_kind(s: Setting) -> dict:
    tp = s.type
    if tp is bool:
        return {"action": argparse.BooleanOptionalAction}
    item = _item_type(tp) if typing.get_origin(tp) is tuple else tp
    # with choices and no metavar, argparse shows the choices
    metavar = s.metavar or (None if s.choices else _METAVARS.get(item, "JSON"))
    if tp in _SCALARS:
        return {"type": tp, "choices": s.choices, "metavar": metavar}
    if isinstance(metavar, tuple):
        return {"type": item, "nargs": len(metavar), "metavar": metavar}
    if item is not tp:
        return {"type": item, "nargs": "+", "action": "extend", "choices": s.choices, "metavar": metavar}
    return {"type": _json_flag, "metavar": metavar}


def _json_flag(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not JSON: {exc}") from None


def given_flags(args: argparse.Namespace, cls: type) -> dict[str, Any]:
    """The settings given on the command line."""
    return {name: getattr(args, name) for name in specs(cls) if getattr(args, name, None) is not None}


# -- documentation -----------------------------------------------------------------------------
def markdown(cls: type) -> str:
    """The settings of `cls` as Markdown: a table of its own, then one per part."""
    by_part: dict[str, list[Setting]] = {}
    for s in specs(cls).values():
        by_part.setdefault(s.part, []).append(s)
    blocks = []
    for name, rows in by_part.items():
        head = [f"**{name}**: {parts(cls)[name]}", ""] if name else []
        table = ["| setting | type | default | what |", "|---|---|---|---|"]
        table += [_row(s) for s in rows]
        blocks.append("\n".join(head + table))
    return "\n\n".join(blocks) + "\n"


def _row(s: Setting) -> str:
    cell = lambda text: text.replace("|", "\\|").replace("\n", " ")        # noqa: E731
    default = cell(s.shown) if s.shown else f"`{cell(s.default_text)}`"
    help = cell(s.help)
    if s.choices is not None:
        help += "; one of " + ", ".join(f"`{cell(toml_literal(c))}`" for c in s.choices)
    return f"| `{s.name}` | {_type_name(s.type)} | {default} | {help} |"


def toml_table(cls: type, table: str) -> str:
    """The settings as a TOML table of commented-out defaults: a start for a profile."""
    lines = [f"[{table}]"]
    lines += [f"# {s.name} = {toml_literal(s.default)}    # {s.help}" for s in specs(cls).values()]
    return "\n".join(lines) + "\n"
