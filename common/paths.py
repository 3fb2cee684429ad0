"""Where the files viena reads at run time are: compose profiles, zenoh configs, recordings.

They live at the top of the repository (compose/, data/) and reach the package through
the links viena/profiles and viena/data, which a wheel turns into plain folders; so the
same paths work from a checkout, an editable install and an installed wheel, from any
working directory. VIENA_COMPOSE points `viena up` at other profiles (tests use it).
The package's folder is asked of the import system: common/ resolves to the repository's
top in a checkout, where no profiles/ link is.
"""
from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path

PACKAGE = Path(str(files("viena")))


def compose_dir() -> Path:
    """The profiles: `<profile>.conf`, `<profile>.toml`, programs/, zenoh/."""
    return Path(os.environ.get("VIENA_COMPOSE") or (PACKAGE / "profiles").resolve())


def router_config() -> Path:
    return compose_dir() / "zenoh" / "router.json5"


def drives_dir() -> Path:
    """Where the black box keeps its drives unless told: $VIENA_DRIVES, else
    ~/.local/share/viena/drives ($XDG_DATA_HOME respected)."""
    if os.environ.get("VIENA_DRIVES"):
        return Path(os.environ["VIENA_DRIVES"]).expanduser()
    base = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return Path(base) / "viena" / "drives"
