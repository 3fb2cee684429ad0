"""Configuration: TOML for viena's settings, JSON5 for zenoh's.

A viena TOML file holds one table per service, with one sub-table per unit:

    car = "elettra"
    [zenoh]
    connect = ["tcp/192.168.1.10:7447"]     # or: config = "compose/zenoh/client.json5"
    [gnss.gnss0]
    port = "/dev/ttyUSB0"

Text values may name environment variables as `${NAME}` or `${NAME:-default}`, so one
profile serves every machine (compose profiles use this for ports and addresses).
Every mistake is a ConfigError whose one line names the file and the setting.
"""
from __future__ import annotations

import json
import os
import re
import tomllib
from pathlib import Path
from typing import Any

import json5

from viena.common.errors import ConfigError
from viena.common.settings import convert

MULTICAST_OFF = "scouting/multicast/enabled"
#: zenoh's runtime (its ZENOH_RUNTIME variable) on one worker thread, every other pool
#: handing its work over to it: for a process that only takes samples in. The black box
#: spent some 20 % less CPU so (`viena bench pi`, 3 runs each way: 3.4 % of a core against
#: 4.3 %); the device services and the estimator showed no difference beyond the noise.
ONE_THREAD_RUNTIME = ("(app: (worker_threads: 1), acc: (handover: app), tx: (max_blocking_threads: 1), "
                      "rx: (handover: app), net: (handover: app))")


def use_one_thread_runtime() -> None:
    """Run this process's zenoh on ONE_THREAD_RUNTIME, unless ZENOH_RUNTIME says otherwise;
    before its first session (zenoh reads the variable once, when it starts its runtime)."""
    os.environ.setdefault("ZENOH_RUNTIME", ONE_THREAD_RUNTIME)


_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


def expand_env(value: Any, source: str = "config") -> Any:
    """Replace ${NAME} and ${NAME:-default} in every text value, recursively."""
    if isinstance(value, dict):
        return {k: expand_env(v, f"{source}.{k}") for k, v in value.items()}
    if isinstance(value, list):
        return [expand_env(v, source) for v in value]
    if not isinstance(value, str) or "${" not in value:
        return value

    def one(m: re.Match) -> str:
        name, default = m.group(1), m.group(2)
        if name in os.environ:
            return os.environ[name]
        if default is None:
            raise ConfigError(f"{source}: environment variable {name} is not set")
        return default
    return _VAR.sub(one, value)


def load_toml(path: str | Path) -> dict:
    path = Path(path)
    try:
        with path.open("rb") as f:
            return expand_env(tomllib.load(f), str(path))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: {exc.strerror}") from None


def merge_settings(defaults: dict, given: dict, source: str) -> dict:
    """Defaults overlaid with `given`; unknown names and wrong types are errors. For the
    small tables declared as a dict (the twins' [sim.<name>]); a service's settings are a
    dataclass (common/settings.py)."""
    out = dict(defaults)
    for name, value in given.items():
        if name not in defaults:
            known = ", ".join(sorted(defaults)) or "none"
            raise ConfigError(f"{source}: unknown setting '{name}' (known: {known})")
        out[name] = check_type(name, value, defaults[name], source)
    return out


def check_type(name: str, value: Any, default: Any, source: str) -> Any:
    """`value` as the type of `default` (None on either side: as it is)."""
    if default is None or value is None:
        return value
    return convert(value, type(default), name, source)


def load_zenoh_config(path: str | Path | None = None, *, mode: str | None = None,
                      connect: list[str] | None = None, listen: list[str] | None = None):
    """A zenoh.Config from a JSON5 file (or defaults), with overrides, multicast off."""
    import zenoh

    if path is not None:
        path = Path(path)
        try:
            text = path.read_text()
            json5.loads(text)                   # zenoh's own message lacks file and line
        except FileNotFoundError:
            raise ConfigError(f"{path}: no such file") from None
        except ValueError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        try:
            conf = zenoh.Config.from_json5(text)
        except Exception as exc:
            raise ConfigError(f"{path}: {exc}") from None
    else:
        conf = zenoh.Config()
    try:
        if mode:
            conf.insert_json5("mode", json.dumps(mode))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        # no multicast anywhere, whatever a file says (docs/placement.md#zenoh-topology)
        conf.insert_json5(MULTICAST_OFF, "false")
    except Exception as exc:
        raise ConfigError(f"{path or 'zenoh config'}: {exc}") from None
    return conf
