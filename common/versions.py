"""Which viena, zenoh and Python a process runs, for `--version`, `viena doctor` and each
process's info (common/samples/info.py): read from the installed distributions' names, so
that asking costs no imports (importlib.metadata brings ~45 modules, 1.7 MB a process)."""
from __future__ import annotations

import os
import platform
import sys


def installed_versions(*dists: str) -> dict[str, str]:
    """Distributions' versions from their `NAME-VERSION.dist-info` folders on sys.path (what
    importlib.metadata reads too), in one pass over it; "not installed" for one without."""
    wanted = {dist.replace("-", "_").lower(): dist for dist in dists}
    found: dict[str, str] = {}
    for entry in sys.path:
        try:
            names = os.listdir(entry or ".")
        except OSError:
            continue
        for name in names:
            stem, _, ext = name.rpartition(".")
            dist = wanted.get(stem.partition("-")[0].lower()) if ext == "dist-info" else None
            if dist is not None:
                found.setdefault(dist, stem.partition("-")[2])   # the first on sys.path, as import finds it
    return {dist: found.get(dist, "not installed") for dist in dists}


def versions() -> dict[str, str]:
    """viena's, zenoh's, Python's and the machine's."""
    return {**installed_versions("viena", "eclipse-zenoh"),
            "python": platform.python_version(), "platform": f"{platform.system()} {platform.machine()}"}


def version_text() -> str:
    """`0.1.0 (eclipse-zenoh 1.10.2, Python 3.11.2, Linux aarch64)`."""
    v = versions()
    return f"{v['viena']} (eclipse-zenoh {v['eclipse-zenoh']}, Python {v['python']}, {v['platform']})"
