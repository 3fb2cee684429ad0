"""A viena Schema as JSON Schema: the same fields, types and bounds as its own checks."""
from __future__ import annotations

import json

import jsonschema
import pytest
from laptop_helpers import write_drive

import viena.foxglove_messages  # noqa: F401  (registers every schema of the car)
from viena.common.json_schema import JsonForm, field_schema, json_schema
from viena.common.payload import to_jsonable
from viena.common.recording import Recording
from viena.common.schema import SCHEMAS, F, SampleError, Schema

CAR_SCHEMAS = ["viena.gnss.fix/1", "viena.imu.sample/1", "viena.steering.state/1",
               "viena.estimator.state/2", "viena.sim.truth/1", "viena.health/1", "viena.pilot.state/1"]
EXAMPLE = Schema("viena.test.jsonschema/1", {
    "t": F.time, "seq": F.int, "x_m": F.float, "ok": F.bool, "name": F.str,
    "mode": F.enum("a", "b"), "v": F.vec(3), "names": F.list(F.str), "extra": F.map,
    "anything": F.any, "maybe": F.optional(F.vec(2)),
    "inner": F.struct({"y_m": F.float, "z": F.optional(F.int)}),
})
GOOD = {"t": 1_700_000_000_000_000_000, "seq": 3, "x_m": 1.5, "ok": True, "name": "n", "mode": "b",
        "v": [1.0, 2.0, 3.0], "names": ["p"], "extra": {"k": 1}, "anything": [1, "x"], "maybe": None,
        "inner": {"y_m": 2.0}}


def validator(schema: Schema):
    return jsonschema.Draft202012Validator(json_schema(schema))


@pytest.mark.parametrize("name", CAR_SCHEMAS)
def test_every_schema_of_the_car_is_a_valid_json_schema(name):
    js = json_schema(SCHEMAS[name])
    jsonschema.Draft202012Validator.check_schema(js)
    assert js["title"] == name and js["type"] == "object"
    assert set(js["properties"]) == set(SCHEMAS[name].fields)
    assert all("type" in p for p in js["properties"].values())         # every field, typed
    json.dumps(js)                                                     # and JSON itself


def test_a_sample_its_schema_accepts_validates_and_one_it_refuses_does_not():
    v, form = validator(EXAMPLE), JsonForm(EXAMPLE)
    assert "maybe" not in form.value(GOOD) and "maybe" in GOOD            # nil optional: left out
    v.validate(form.value(GOOD))
    v.validate(form.value({**GOOD, "maybe": [1.0, 2.0], "inner": {"y_m": 2.0, "z": None}}))
    v.validate({**form.value(GOOD), "newer_field": 1})  # decode keeps a newer producer's fields
    bad = [{**GOOD, "x_m": "1.5"}, {**GOOD, "v": [1.0, 2.0]}, {**GOOD, "mode": "c"},
           {**GOOD, "t": 5}, {**GOOD, "seq": 1.5}, {**GOOD, "inner": {"z": 1}},
           {**GOOD, "names": [1]}, {**GOOD, "maybe": [1.0]}, {k: v for k, v in GOOD.items() if k != "ok"}]
    for sample in bad:
        with pytest.raises(SampleError):
            EXAMPLE.validate(dict(sample), strict=False)               # viena refuses it ...
        assert not v.is_valid(form.value(sample)), sample              # ... and so does its JSON Schema


def test_recorded_samples_validate_as_json(tmp_path):
    path = tmp_path / "drive.mcap"
    write_drive(path, seconds=3.0)
    checked = 0
    for msg in Recording(path).messages():
        schema = SCHEMAS[msg.schema]
        validator(schema).validate(to_jsonable(JsonForm(schema).value(schema.decode(msg.data))))
        checked += 1
    assert checked == 300 + 30 + 60 + 60


def test_a_field_check_it_does_not_know_is_an_error_not_an_empty_schema():
    with pytest.raises(ValueError, match="teach"):
        field_schema(lambda v: v)
    with pytest.raises(ValueError, match="teach"):
        field_schema(F.enum("x", 1))
    assert field_schema(F.optional(F.enum("x"))) == {"type": "string", "enum": ["x"]}
    assert field_schema(F.any) is None and "anything" not in json_schema(EXAMPLE)["properties"]


LICHTBLICK_TYPES = {"boolean", "string", "number", "integer", "object", "array"}


def readable_by_lichtblick(schema: dict, where: str) -> None:
    """What Foxglove's and Lichtblick's parseJsonSchema (packages/mcap-support) accept: an
    object with properties, each with one plain type, arrays of a plain type."""
    assert schema.get("type") == "object" and isinstance(schema.get("properties"), dict), where
    for name, field in schema["properties"].items():
        assert field.get("type") in LICHTBLICK_TYPES, f"{where}.{name}: {field}"
        if field["type"] == "object":
            readable_by_lichtblick(field, f"{where}.{name}")
        if field["type"] == "array":
            item = field["items"]
            assert item.get("type") in LICHTBLICK_TYPES - {"array"}, f"{where}.{name}[]: {item}"
            if item["type"] == "object":
                readable_by_lichtblick(item, f"{where}.{name}[]")


@pytest.mark.parametrize("name", CAR_SCHEMAS)
def test_foxglove_and_lichtblick_can_read_every_schema(name):
    readable_by_lichtblick(json_schema(SCHEMAS[name]), name)
