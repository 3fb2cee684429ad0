"""Layers that point one way: the command-line tools (viena/*.py) use common/ and the
services, never the other way round. What a lower layer needs of the tools (the recording
format, where a running profile keeps its state, where the profiles are) lives in common/."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: the tools room: every module file directly in viena/ (common/, services/, data/, profiles/ are links)
TOOLS = {p.stem for p in (REPO / "viena").glob("*.py") if p.stem != "__init__"}
LOWER = [*sorted((REPO / "common").rglob("*.py")), *sorted((REPO / "services").rglob("*.py"))]


def module_name(path: Path) -> str:
    """`viena.common.x.y` for common/x/y.py (a package's __init__ is the package)."""
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["viena", *parts])


def imported(source: str, module: str, is_package: bool = False) -> set[str]:
    """Every module (and `from M import name`'s M.name) that `source`, the text of
    `module`, imports, with relative imports made absolute."""
    found: set[str] = set()
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names}
    return found


def tool_modules(names: set[str]) -> set[str]:
    """The names among `names` that are (or reach into) a module of the tools room."""
    return {n for n in names if n.split(".")[0] == "viena" and len(n.split(".")) > 1 and n.split(".")[1] in TOOLS}


def test_the_rooms_are_seen():
    assert {"cli", "record", "keys_cli", "settings_cli"} <= TOOLS
    assert not TOOLS & {"common", "services", "data", "profiles"}
    assert len(LOWER) > 100


@pytest.mark.parametrize("source", [
    "from viena.record import main",
    "import viena.compose",
    "from viena import cli",
    "from .. import record",           # in viena.common.x: viena.record
])
def test_an_upward_import_is_found(source):
    assert tool_modules(imported(source, "viena.common.x"))


@pytest.mark.parametrize("source", [
    "from viena.common.recording import Recording",
    "from viena import common",
    "from viena.services.gnss.model import fix",
    "from . import keys",              # in viena.common.x: viena.common.keys
])
def test_a_downward_import_is_not(source):
    assert not tool_modules(imported(source, "viena.common.x"))


def test_common_and_services_import_no_tool():
    """Nothing under common/ or services/ imports a module of viena/*.py, at any depth of
    the file (function-level imports too)."""
    upward = {}
    for path in LOWER:
        found = tool_modules(imported(path.read_text(), module_name(path), path.name == "__init__.py"))
        if found:
            upward[str(path.relative_to(REPO))] = sorted(found)
    assert upward == {}


def test_no_tool_shares_a_name_with_a_common_module():
    """`viena/keys.py` next to `common/keys.py` read as one thing: the tools that
    drive a library module say so (`keys_cli`, `settings_cli`)."""
    common = {p.stem for p in (REPO / "common").glob("*.py")} - {"__init__"}
    assert TOOLS & common == set()
