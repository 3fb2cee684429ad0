"""The rule for evolving a schema, as code: today's readers read a sample of every version
any earlier commit published (tests/data/schema_history/, kept by scripts/schema_history.py).

A field added as required, or a field removed that a reader still needs, fails here on the
older samples: make the field optional, or bump the version and retire the old name on its
topic (docs/dataflow.md#evolving-a-schema)."""
from __future__ import annotations

import importlib
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from viena.common.errors import SampleError
from viena.common.recording import decode_value
from viena.common.samples.topics import BY_SCHEMA, RETIRED, TOPICS
from viena.common.schema import READERS, SCHEMAS, F, Schema

REPO = Path(__file__).resolve().parents[1]
STORE = REPO / "tests" / "data" / "schema_history"
INDEX = json.loads((STORE / "index.json").read_text())
sys.path.insert(0, str(REPO / "scripts"))
from schema_history import describe  # noqa: E402


def _import_readers() -> list[str]:
    """Every product module that makes a Reader when imported (the readers are theirs)."""
    names = []
    for root in ("common", "services", "viena"):
        for path in sorted((REPO / root).rglob("*.py") if root != "viena" else (REPO / root).glob("*.py")):
            if re.search(r"^\w+ = [\w.]+\.reader\(", path.read_text(), re.M):
                parts = list(path.relative_to(REPO).with_suffix("").parts)
                names.append(".".join(["viena", *parts] if parts[0] != "viena" else parts))
    for name in names:
        importlib.import_module(name)
    return names


READER_MODULES = _import_readers()


def stored(entry: dict) -> bytes:
    return (STORE / entry["file"]).read_bytes()


def test_today_s_version_of_every_schema_is_stored():
    shapes = {(e["schema"], json.dumps(e["shape"], sort_keys=True)) for e in INDEX}
    for topic in TOPICS:
        if topic.schema is None:
            continue
        shape = json.dumps({k: describe(c) for k, c in topic.schema.fields.items()}, sort_keys=True)
        assert (topic.schema.name, shape) in shapes, (
            f"{topic.schema.name} changed: run `.venv/bin/python scripts/schema_history.py` to store a "
            "sample of the new version (and keep the old ones)")


def test_the_store_and_its_index_agree():
    assert sorted([*(e["file"] for e in INDEX), *(e["minimal_file"] for e in INDEX)]) == sorted(
        p.name for p in STORE.glob("*.msgpack"))
    assert len({e["schema"] for e in INDEX}) >= 10
    assert {e["schema"] for e in INDEX} <= set(BY_SCHEMA) | set(RETIRED)


def test_readers_are_found():
    assert {"viena.services.pilot.model.estimate", "viena.services.steering.service",
            "viena.common.samples.fix"} <= set(READER_MODULES)
    assert len(READERS["viena.estimator.state/2"]) >= 2


@pytest.mark.parametrize("minimal", [False, True], ids=["every_field", "no_optional_field"])
@pytest.mark.parametrize("entry", INDEX, ids=lambda e: e["file"].removesuffix(".msgpack"))
def test_every_earlier_version_is_read_by_today_s_code(entry, minimal):
    """Each version as sent with every optional field, and without any (a producer older
    than the fields): today's schema decodes it, every Reader made on it and its topic's
    typed reader read it, its monitor view shows it."""
    payload = (STORE / entry["minimal_file" if minimal else "file"]).read_bytes()
    name = entry["schema"]
    if name in RETIRED:
        # a retired version is still data: replay, export and plot show it as a plain map
        value = decode_value(payload, f"application/msgpack;{name}")
        assert set(value) <= set(entry["shape"]) and value
        assert name not in SCHEMAS and RETIRED[name].schema.name in SCHEMAS
        return
    schema = SCHEMAS[name]
    sample = schema.decode(payload)
    for reader in list(READERS.get(name, ())):
        reader(dict(sample))
    topic = BY_SCHEMA[name]
    if topic.read is not None:
        topic.read(dict(sample))
    if topic.view is not None:
        assert isinstance(topic.view(dict(sample)), dict)


def test_the_minimal_samples_leave_out_the_optional_fields():
    fix = next(e for e in INDEX if e["schema"] == "viena.gnss.fix/1" and "diff_age_s" in e["shape"])
    full = SCHEMAS["viena.gnss.fix/1"].decode(stored(fix))
    minimal = SCHEMAS["viena.gnss.fix/1"].decode((STORE / fix["minimal_file"]).read_bytes())
    assert "diff_age_s" in full and "diff_age_s" not in minimal and "ecef_m" in minimal


def test_a_required_field_added_without_a_new_version_is_caught():
    """The test above can fail: the stored fixes lack a field a careless change would
    require, whether new or an optional one made required."""
    fix = SCHEMAS["viena.gnss.fix/1"]
    careless = Schema("viena.test.careless_fix/1", {**fix.fields, "new_field": F.float})
    required = Schema("viena.test.required_fix/1", {**fix.fields, "diff_age_s": F.float})
    try:
        old = [e for e in INDEX if e["schema"] == "viena.gnss.fix/1"]
        assert len(old) >= 2
        with pytest.raises(SampleError, match="missing field 'new_field'"):
            careless.decode(stored(old[0]))
        with pytest.raises(SampleError, match="missing field 'diff_age_s'"):
            required.decode((STORE / old[-1]["minimal_file"]).read_bytes())
        optional = Schema("viena.test.careful_fix/1", {**fix.fields, "new_field": F.optional(F.float)})
        assert optional.decode(stored(old[0]))["seq"] == 7
    finally:
        SCHEMAS.pop("viena.test.careless_fix/1", None)
        SCHEMAS.pop("viena.test.required_fix/1", None)
        SCHEMAS.pop("viena.test.careful_fix/1", None)


@pytest.mark.slow
def test_every_version_in_the_history_is_stored():
    """Every distinct version any commit had (read from git) has its sample here."""
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "schema_history.py"), "--check"],
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    assert run.returncode == 0, run.stdout + run.stderr
