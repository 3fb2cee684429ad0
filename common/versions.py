"""Which viena, zenoh and Python a process runs, for `--version`, `viena doctor` and each
process's info (common/samples/info.py): read from the installed distributions' names, so
that asking costs no imports (importlib.metadata brings ~45 modules, 1.7 MB a process)."""
from __future__ import annotations

import os
import platform
import sys


def installed_version(dist: str) -> str:
    """A distribution's version from its `NAME-VERSION.dist-info` folder on sys.path, which
    is what importlib.metadata reads too; "not installed" when there is none."""
    wanted = dist.replace("-", "_").lower()
    for entry in sys.path:
        try:
            names = os.listdir(entry or ".")
        except OSError:
            continue
        for name in names:
            stem, _, ext = name.rpartition(".")
            if ext == "dist-info" and stem.partition("-")[0].lower() == wanted:
                return stem.partition("-")[2]
    return "not installed"


def versions() -> dict[str, str]:
    """viena's, zenoh's, Python's and the machine's."""
    return {"viena": installed_version("viena"), "eclipse-zenoh": installed_version("eclipse-zenoh"),
            "python": platform.python_version(), "platform": f"{platform.system()} {platform.machine()}"}


def version_text() -> str:
    """`0.1.0 (eclipse-zenoh 1.10.2, Python 3.11.2, Linux aarch64)`."""
    v = versions()
    return f"{v['viena']} (eclipse-zenoh {v['eclipse-zenoh']}, Python {v['python']}, {v['platform']})"
