"""Where the repository's shipped files are: compose profiles and zenoh configs."""
from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def compose_dir() -> Path:
    return Path(os.environ.get("VIENA_COMPOSE", REPO / "compose"))


def router_config() -> Path:
    return compose_dir() / "zenoh" / "router.json5"
