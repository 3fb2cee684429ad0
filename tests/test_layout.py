"""The layout tools can read: every module has one import name (viena.*), and an editor's
go-to-definition (jedi, as used by most Python editors) resolves every viena import of the
repository to a file of the repository, from the editable install."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = [*sorted((REPO / "common").rglob("*.py")), *sorted((REPO / "services").rglob("*.py")),
           *sorted(p for p in (REPO / "viena").glob("*.py"))]


@pytest.mark.parametrize("module", ["common.errors", "services.gnss.fix", "common"])
def test_common_and_services_have_one_import_name(module):
    """From the repository root `common` is on the path too; importing it so is refused,
    so no module ever loads twice with two sets of classes."""
    run = subprocess.run([sys.executable, "-c", f"import {module}"], cwd=REPO, capture_output=True,
                         text=True, timeout=60)
    assert run.returncode != 0
    assert "ImportError: import viena." in run.stderr


def test_the_package_is_the_repository():
    import viena.common.errors
    import viena.common.samples.fix

    for module in (viena.common.errors, viena.common.samples.fix):
        path = Path(module.__file__).resolve()
        assert path.is_relative_to(REPO) and "site-packages" not in str(module.__file__)


def viena_imports(path: Path):
    """(line, column) of every name imported from a viena module in `path`."""
    tree = ast.parse(path.read_text(), str(path))
    lines = path.read_text().splitlines()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("viena"):
            for alias in node.names:
                if alias.name == "*":
                    continue
                # the imported name's own position, found on the statement's lines
                for line_no in range(node.lineno, (node.end_lineno or node.lineno) + 1):
                    col = _find_word(lines[line_no - 1], alias.name)
                    if col is not None:
                        yield line_no, col, f"{node.module}.{alias.name}"
                        break


def _find_word(line: str, word: str) -> int | None:
    import re

    m = re.search(rf"(?<![\w.]){re.escape(word)}(?!\w)", line.split("#")[0])
    return m.start() if m else None


@pytest.mark.slow
def test_editors_resolve_every_viena_import():
    jedi = pytest.importorskip("jedi")
    project = jedi.Project(REPO, environment_path=sys.prefix)
    unresolved = []
    checked = 0
    for path in SOURCES:
        script = jedi.Script(path=str(path), project=project)
        for line, col, name in viena_imports(path):
            found = script.goto(line, col, follow_imports=True)
            checked += 1
            if not any(d.module_path and Path(d.module_path).resolve().is_relative_to(REPO) for d in found):
                unresolved.append(f"{path.relative_to(REPO)}:{line} {name}")
    assert checked > 300
    assert unresolved == []


# -- the rooms --------------------------------------------------------------------------------
DEVICES = ("gnss", "imu", "ntrip", "steering")
#: what each room of a device service must never import
FORBIDDEN = {
    "driver": {"zenoh", "msgpack"},
    "model": {"zenoh", "msgpack", "socket", "serial", "can", "canopen", "subprocess", "threading", "time"},
    "simulator": {"zenoh"},
}


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    found = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    found |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module and n.level == 0}
    return {m.split(".")[0] for m in found} | found


@pytest.mark.parametrize("room", sorted(FORBIDDEN))
def test_each_room_keeps_to_itself(room):
    """driver: bytes, no zenoh; model: no zenoh and no I/O, no threads, no clock; simulator:
    the twin, no zenoh. Every device folder has a driver and a simulator; a model room where
    the device has logic of its own beyond its sample (whose contract is in common/samples/)."""
    for device in DEVICES:
        files = sorted((REPO / "services" / device / room).rglob("*.py"))
        assert files or room == "model", f"services/{device} has no {room}/ room"
        for path in files:
            assert not imported_modules(path) & FORBIDDEN[room], path.relative_to(REPO)


def test_no_service_module_outside_the_rooms_touches_bytes():
    """Device services are zenoh glue: protocol bytes (struct, crc) stay in the driver."""
    for device in DEVICES:
        for path in (REPO / "services" / device).glob("*.py"):
            assert not imported_modules(path) & {"struct", "zlib", "binascii"}, path.relative_to(REPO)
