"""Store one sample of every version of every sample schema the repository has ever had.

    .venv/bin/python scripts/schema_history.py          # add the versions not stored yet
    .venv/bin/python scripts/schema_history.py --check  # exit 1 if one is missing

Run it after changing a schema's fields (tests/test_schema_history.py says so when you
forget). It reads the schemas as each commit of this repository wrote them (`git grep`
for `= Schema("viena.` in every commit), makes a sample that commit's schema accepts,
packs it as msgpack (what that commit's publisher sent and its recorder stored) and keeps
it in tests/data/schema_history/, two files per distinct version (with every optional
field, and without any), named by the schema and the first commit that had it. Samples
already stored are never rewritten: they are the record of what older recordings hold,
which today's readers must keep reading (docs/dataflow.md#evolving-a-schema). A schema of
an old commit that can no longer be rebuilt (a constant it named has moved) is reported,
and makes --check fail, rather than silently skipped.
"""
from __future__ import annotations

import argparse
import ast
import json
import subprocess
import sys
from pathlib import Path

import msgpack

REPO = Path(__file__).resolve().parents[1]
STORE = REPO / "tests" / "data" / "schema_history"
INDEX = STORE / "index.json"
#: schemas that cross no process (the Foxglove bridge's own messages) are not contracts
SKIP = ("viena.foxglove.", "viena.example", "viena.doc.")
T_NS = 1_700_000_000_000_000_000
#: old modules whose schemas could not all be rebuilt (versions() fills it)
LOST: list[str] = []


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout


class _Recorded:
    """Stands in for `Schema` while an old module runs: keeps the name and fields only."""
    found: list[tuple[str, dict]] = []

    def __init__(self, name: str, fields: dict):
        self.name, self.fields = name, fields
        _Recorded.found.append((name, fields))


def schemas_in(source: str) -> list[tuple[str, dict]]:
    """The (name, fields) of every `X = Schema("viena....", {...})` in an old module's source,
    its fields made with today's `F`. The module's statements run one by one in order and
    those that fail (an import of something since moved) are skipped: a schema's fields
    need only F and the module's own constants."""
    from viena.common.schema import F

    _Recorded.found = []
    scope: dict = {"__name__": "schema_history_old_module"}
    tree = ast.parse(source)
    declared = sum(1 for node in tree.body if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)
                   and isinstance(node.value.func, ast.Name) and node.value.func.id == "Schema"
                   and node.value.args and isinstance(node.value.args[0], ast.Constant)
                   and str(node.value.args[0].value).startswith("viena.")
                   and not str(node.value.args[0].value).startswith(SKIP))
    for node in tree.body:
        code = compile(ast.Module([node], []), "<old>", "exec")
        try:
            exec(code, scope)
        except Exception:      # noqa: BLE001 - an old statement that no longer runs is skipped
            pass
        scope["F"], scope["Schema"] = F, _Recorded
    found = [(n, f) for n, f in _Recorded.found if not n.startswith(SKIP)]
    if len(found) != declared:              # a version this script could not rebuild: say so
        raise LostVersion(f"{declared} schemas declared, {len(found)} rebuilt")
    return found


class LostVersion(Exception):
    """An old module's schema that no longer runs (a constant it named has moved)."""


def describe(check) -> object:
    """A check's shape, to tell versions apart: the F builder and its arguments."""
    from viena.common.schema import F

    kind, made = getattr(check, "made", ("", {}))
    if kind == "vec":
        return ["vec", made["n"]]
    if kind in ("list", "optional"):
        return [kind, describe(made["item" if kind == "list" else "inner"])]
    if kind == "enum":
        return ["enum", sorted(made["allowed"])]
    if kind == "struct":
        return ["struct", {k: describe(c) for k, c in made["fields"].items()}]
    for name in ("float", "int", "time", "str", "bool", "any", "map"):
        if check is getattr(F, name):
            return name
    return kind or getattr(check, "__name__", "?")


def example(shape, minimal: bool = False) -> object:
    """A value the described check keeps; `minimal`: with every optional field left out
    (of a struct), as an older producer that never knew them sent it."""
    if isinstance(shape, list):
        kind = shape[0]
        if kind == "vec":
            return [0.25 * (i + 1) for i in range(shape[1])]
        if kind in ("list", "optional"):
            inner = example(shape[1], minimal)
            return [inner] if kind == "list" else inner
        if kind == "enum":
            return shape[1][0]
        if kind == "struct":
            return sample_of(shape[1], minimal)
    return {"float": 1.5, "int": 7, "time": T_NS, "str": "text", "bool": True, "any": "anything",
            "map": {"name": 1.0}, "_bytes": b"\xd3\x00\x00"}.get(shape, None)   # _bytes: the corrections' data


def sample_of(shape: dict, minimal: bool = False) -> dict:
    """A sample of a version's fields (`minimal`: its optional fields left out)."""
    return {k: example(v, minimal) for k, v in shape.items()
            if not (minimal and isinstance(v, list) and v[0] == "optional")}


def versions() -> dict[str, dict]:
    """Every distinct (schema, fields) in the history, oldest commit first: key -> entry."""
    found: dict[str, dict] = {}
    for commit in git("rev-list", "--reverse", "HEAD").split():
        try:
            paths = git("grep", "-l", "-e", '= Schema("viena\\.', commit, "--", "*.py").split()
        except subprocess.CalledProcessError:
            continue
        for ref in paths:
            path = ref.split(":", 1)[1]
            if path.startswith(("tests/", "benchmarks/", "scripts/")):
                continue
            try:
                schemas = schemas_in(git("show", ref))
            except LostVersion as exc:
                LOST.append(f"{commit[:7]} {path}: {exc}")
                continue
            for name, fields in schemas:
                shape = {k: describe(c) for k, c in fields.items()}
                key = f"{name} {json.dumps(shape, sort_keys=True)}"
                if key not in found:
                    found[key] = {"schema": name, "commit": commit[:7], "date": git(
                        "show", "-s", "--format=%cs", commit).strip(), "path": path, "shape": shape}
    for name, fields in current().items():        # a change not committed yet
        shape = {k: describe(c) for k, c in fields.items()}
        key = f"{name} {json.dumps(shape, sort_keys=True)}"
        found.setdefault(key, {"schema": name, "commit": "worktree", "date": "", "path": "", "shape": shape})
    return found


def current() -> dict[str, dict]:
    """Today's contracts: every schema on the table of topics, by name."""
    from viena.common.samples.topics import TOPICS

    return {t.schema.name: t.schema.fields for t in TOPICS if t.schema is not None}


def file_name(entry: dict) -> str:
    return f"{entry['schema'].removeprefix('viena.').replace('/', '@')}-{entry['commit']}.msgpack"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only say whether a version is missing")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO.parent))
    index = json.loads(INDEX.read_text()) if INDEX.exists() else []
    stored = {(e["schema"], json.dumps(e["shape"], sort_keys=True)) for e in index}
    missing = [e for e in versions().values() if (e["schema"], json.dumps(e["shape"], sort_keys=True)) not in stored]
    for e in missing:
        print(f"{'missing' if args.check else 'storing'} {e['schema']} as of {e['commit']} ({e['date']}, {e['path']})")
    for line in LOST:
        print(f"cannot rebuild: {line}")
    if args.check:
        return 1 if missing or LOST else 0
    STORE.mkdir(parents=True, exist_ok=True)
    for e in missing:
        e["file"] = file_name(e)
        (STORE / e["file"]).write_bytes(msgpack.packb(sample_of(e["shape"]), use_bin_type=True))
        index.append(e)
    for e in index:                         # and each version as sent without its optional fields
        if "minimal_file" not in e:
            e["minimal_file"] = e["file"].replace(".msgpack", "-minimal.msgpack")
            (STORE / e["minimal_file"]).write_bytes(msgpack.packb(sample_of(e["shape"], minimal=True),
                                                                  use_bin_type=True))
    INDEX.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    print(f"{len(index)} versions stored, {len(missing)} new")
    return 0


if __name__ == "__main__":
    sys.exit(main())
