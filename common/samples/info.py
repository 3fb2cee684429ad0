"""viena.info/1 on viena/<car>/<service>[/<unit>]/info (at start, then every 10 s; latched):
who a process is, in one sample: its versions, its host, and the settings it runs with after
its file and its flags. The black box repeats the last one of every process at the start of
every split file, so each file says what made it (services/recorder/README.md). Settings
never hold a secret (a login is a file's name: services/ntrip)."""
from __future__ import annotations

import dataclasses
from typing import Any

from viena.common.display import fields_view
from viena.common.schema import F, Schema

INFO = Schema("viena.info/1", {
    "t": F.time,
    "seq": F.int,
    "service": F.str,
    "unit": F.optional(F.str),
    "started": F.time,            # when the process started (ns UTC)
    "host": F.str,
    "versions": F.map,            # viena, eclipse-zenoh, python, platform
    "settings": F.map,            # name -> value, as the process runs them
})


def settings_map(settings: Any) -> dict[str, Any]:
    """A settings dataclass as plain values (paths and other objects as text); {} for none."""
    if not dataclasses.is_dataclass(settings) or isinstance(settings, type):
        return {}
    return {f.name: _plain(getattr(settings, f.name)) for f in dataclasses.fields(settings)}


def _plain(value: Any) -> Any:
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return settings_map(value)
    return str(value)                     # paths and anything else


def monitor_view(sample: dict) -> dict[str, str]:
    """How the monitor shows a process's info: its versions and host first."""
    if not isinstance(sample, dict):
        return {}
    view = fields_view({"host": sample.get("host"), **(sample.get("versions") or {})})
    view["settings"] = str(len(sample.get("settings") or {}))
    return view
