"""The table of topics (common/samples/topics.py) is the one place a key is spelled: the
services, tools and access rules take their keys from it, and docs/dataflow.md shows it."""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from viena.common.keys import Keys
from viena.common.samples import topics
from viena.common.samples.topics import BY_NAME, TOPICS, topic_of

REPO = Path(__file__).resolve().parents[1]
PRODUCT = [*sorted((REPO / "common").rglob("*.py")), *sorted((REPO / "services").rglob("*.py")),
           *sorted((REPO / "viena").glob("*.py"))]
#: where keys may be spelled: the table itself
TABLE = {REPO / "common" / "samples" / "topics.py"}
FIRST_CHUNKS = {t.pattern.split("/")[0] for t in TOPICS if not t.pattern.startswith("{")}
CAR_PREFIX = re.compile(r"^(viena/[^/]+/|\{prefix\}/)")
KEY_LIKE = re.compile(r"^[a-z_*{}]+(/[a-z_*{][a-z0-9_*{}]*)+$")


def docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                found.add(id(first.value))
    return found


def spelled_keys(path: Path, root: Path = REPO) -> list[str]:
    """Text in `path` that spells a key of the car: a string (or an f-string's text) shaped
    like one of the table's keys, or a `.key(...)` call given literal parts."""
    tree = ast.parse(path.read_text(), str(path))
    skip = docstrings(tree)
    found = []
    for node in ast.walk(tree):
        text = None
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            text = node.value
        elif isinstance(node, ast.JoinedStr):      # an f-string: {keys.prefix}/... is a car's key
            text = "".join(v.value if isinstance(v, ast.Constant) else
                           "{prefix}" if "prefix" in ast.unparse(v) else "{x}" for v in node.values)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "join"
              and isinstance(node.func.value, ast.Constant) and node.func.value.value == "/"
              and node.args and isinstance(node.args[0], (ast.Tuple, ast.List))):
            text = "/".join(e.value if isinstance(e, ast.Constant) and isinstance(e.value, str) else "{x}"
                            for e in node.args[0].elts)
        if text is not None:
            text = CAR_PREFIX.sub("", text)
        if text is not None and KEY_LIKE.match(text) and text.split("/")[0] in FIRST_CHUNKS:
            found.append(f"{path.relative_to(root)}:{node.lineno} {text!r}")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "key"
              and any(isinstance(a, ast.Constant) and isinstance(a.value, str) for a in node.args)):
            found.append(f"{path.relative_to(root)}:{node.lineno} .key() of literal parts")
    return found


def test_no_key_is_spelled_outside_the_table():
    spelled = [s for p in PRODUCT if p not in TABLE for s in spelled_keys(p)]
    assert spelled == []


def test_the_check_sees_a_spelled_key(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('"""gnss/gnss0/fix in a docstring is fine."""\nKEY = "steering/estop"\n'
                   'x = keys.key("pilot", "state")\ny = f"alive/{kind}/{name}"\nz = f"viena/{car}/gnss/*/fix"\n'
                   'a = f"{keys.prefix}/steering/arm"\nb = "/".join(("pilot", "cmd"))\n')
    found = sorted(s.split(" ", 1)[1] for s in spelled_keys(bad, tmp_path))
    assert found == ["'alive/{x}/{x}'", "'gnss/*/fix'", "'pilot/cmd'", "'steering/arm'", "'steering/estop'",
                     ".key() of literal parts"]


def test_every_topic_is_in_the_doc():
    doc = (REPO / "docs" / "dataflow.md").read_text()
    assert topics.markdown_table() in doc, "docs/dataflow.md#key-expressions: paste topics.markdown_table()"


def test_every_schema_that_crosses_a_process_has_its_topic():
    """Every schema the contracts room declares travels on a topic of the table."""
    from viena.common.schema import Schema

    contracts = set()
    for path in sorted((REPO / "common" / "samples").glob("*.py")):
        module = importlib.import_module(f"viena.common.samples.{path.stem}" if path.stem != "__init__"
                                         else "viena.common.samples")
        contracts |= {v.name for v in vars(module).values() if isinstance(v, Schema)}
    assert len(contracts) == 11
    assert contracts == set(topics.BY_SCHEMA)


@pytest.mark.parametrize("topic", TOPICS, ids=lambda t: t.name)
def test_each_topic_finds_its_own_keys(topic):
    values = {c: f"{c}1" for c in topic.chunks}
    assert topic_of(topic.key(**values)) == (topic, values)
    assert Keys("car").topic_of(Keys("car").of(topic, **values)) == (topic, values)
    assert BY_NAME[topic.name] is topic
    for chunk in topic.chunks:
        assert topic.key(**{chunk: "Q9"}).count("Q9") == 1


def test_keys_of_units_and_services():
    keys = Keys("elettra")
    assert keys.of(topics.GNSS_FIX, unit="gnss0") == "viena/elettra/gnss/gnss0/fix"
    assert keys.of(topics.GNSS_FIX) == "viena/elettra/gnss/*/fix"
    assert keys.health("sim") == "viena/elettra/sim/health"
    assert keys.health("gnss", "gnss1") == "viena/elettra/gnss/gnss1/health"
    assert keys.alive() == "viena/elettra/alive/**"
    assert topic_of("sim/health") == (topics.HEALTH, {"service": "sim"})
    assert topic_of("foo/bar") is None
    assert topics.HEALTH.key(service="sim") == "sim/**/health"      # sim/health, and any unit's
    assert topics.HEALTH.key() == "*/**/health"
    with pytest.raises(ValueError):
        topics.GNSS_FIX.key(unit="a/b")
    with pytest.raises(ValueError):                                # a fix's unit is never absent
        topics.GNSS_FIX.key(unit=None)
    with pytest.raises(TypeError):
        topics.SIM_TRUTH.key(unit="x")
