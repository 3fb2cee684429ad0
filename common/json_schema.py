"""A viena `Schema` as a JSON Schema (draft 2020-12), for tools that read samples as JSON.

Foxglove (and anything else that speaks JSON Schema) needs each channel's fields and
types; viena already lists them, once, in the module that owns the schema
(common/schema.py). This module reads those field checks and says the same thing in JSON
Schema, so there is one source of truth:

    F.float -> number, F.int / F.time -> integer (with the same bounds), F.str -> string,
    F.bool -> boolean, F.map -> object, F.vec(n) -> n numbers, F.list(x) -> array of x,
    F.enum(...) -> string enum, F.struct({...}) -> object, F.optional(x) -> x, not required.

Foxglove's and Lichtblick's readers of JSON Schema (their `parseJsonSchema`) want every
field to have one plain `type` (no `anyOf`, no type lists, no bare `enum`) and every
object its `properties`. So an optional field is not written as "x or null": a nil value
is left out of the sample's JSON instead (`JsonForm.value`: missing and nil mean the same
to viena), and an `F.any` field, which no plain type describes, is left out of
`properties` (unknown fields are allowed, as `Schema.decode` keeps those of newer
producers). A check this module does not know is an error (a new kind of field must be
taught here), never a silently wrong schema.

    >>> from viena.common.schema import F, Schema
    >>> json_schema(Schema("viena.doc.example/1", {"x_m": F.float}))["properties"]
    {'x_m': {'type': 'number'}}
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from viena.common.schema import Check, F, Schema

DIALECT = "https://json-schema.org/draft/2020-12/schema"
_INT = {"type": "integer", "minimum": -(1 << 63), "maximum": (1 << 64) - 1}
_TIME = {"type": "integer", "minimum": 315_964_800_000_000_000, "maximum": 7_258_118_400_000_000_000,
         "description": "absolute time, int ns UTC"}
#: the plain checks, by identity (None: no plain type says it, left out of `properties`)
_PLAIN: dict[Any, dict | None] = {
    F.float: {"type": "number"},
    F.int: _INT,
    F.time: _TIME,
    F.str: {"type": "string"},
    F.bool: {"type": "boolean"},
    F.map: {"type": "object", "properties": {}, "additionalProperties": True},
    F.any: None,
}
_JSON_TYPES = {str: "string", bool: "boolean", int: "integer", float: "number"}


def json_schema(schema: Schema) -> dict:
    """The JSON Schema of `schema`'s samples as JSON (`JsonForm.value`), titled with its
    name (`viena.gnss.fix/1`)."""
    return {"$schema": DIALECT, "title": schema.name, **_object(schema.fields)}


def field_schema(check: Check) -> dict | None:
    """The JSON Schema of one field check (None for a field no plain type describes)."""
    if check in _PLAIN:
        plain = _PLAIN[check]
        return None if plain is None else dict(plain)
    kind, made = _made_by(check)
    if kind == "vec":
        n = made["n"]
        return {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n}
    if kind == "list":
        if is_optional(made["item"]):       # [1.0, null, ...]: no one plain item type (left untyped)
            return None
        item = field_schema(made["item"])
        return {"type": "array", "items": item} if item is not None else None
    if kind == "enum":
        values = sorted(made["allowed"], key=repr)
        types = {_JSON_TYPES.get(type(v)) for v in values}
        if len(types) != 1 or None in types:
            raise ValueError(f"no plain JSON type for the enum {values!r}: teach common/json_schema.py")
        return {"type": types.pop(), "enum": values}
    if kind == "optional":
        return field_schema(made["inner"])
    if kind == "struct":
        return _object(made["fields"])
    raise ValueError(f"no JSON Schema for the field check {check!r}: teach common/json_schema.py")


def is_optional(check: Check) -> bool:
    return getattr(check, "optional", False)


def _object(fields: dict[str, Check]) -> dict:
    properties = {name: s for name, check in fields.items() if (s := field_schema(check)) is not None}
    return {"type": "object", "properties": properties,
            "required": [name for name, check in fields.items() if not is_optional(check) and name in properties],
            "additionalProperties": True}


class JsonForm:
    """A schema's samples as JSON: its JSON Schema, and `value(sample)`, the checked
    sample without the nil values of optional fields (at any depth of F.struct), which
    is what that JSON Schema describes."""

    def __init__(self, schema: Schema):
        self.schema = json_schema(schema)
        self._prune = _pruner(schema.fields)

    def value(self, sample: dict) -> dict:
        return sample if self._prune is None else self._prune(sample)


Pruner = Callable[[dict], dict]


def _pruner(fields: dict[str, Check]) -> Pruner | None:
    """A function dropping nil optional fields from a map of these fields (None: nothing to drop)."""
    optional = frozenset(name for name, check in fields.items() if is_optional(check))
    nested = {name: p for name, check in fields.items() if (p := _inner_pruner(check)) is not None}
    if not optional and not nested:
        return None

    def prune(sample: dict) -> dict:
        out = {k: v for k, v in sample.items() if v is not None or k not in optional}
        for name, inner in nested.items():
            value = out.get(name)
            if isinstance(value, dict):
                out[name] = inner(value)
        return out
    return prune


def _inner_pruner(check: Check) -> Pruner | None:
    kind, made = _made_by(check)
    if kind == "optional":
        return _inner_pruner(made["inner"])
    if kind == "struct":
        return _pruner(made["fields"])
    return None


def _made_by(check: Check) -> tuple[str, dict[str, Any]]:
    """Which F builder made `check` ('vec' for F.vec(3)'s check) and with what (n, item,
    allowed, inner, fields), as common/schema.py records it; ("", {}) for any other."""
    return getattr(check, "made", ("", {}))
