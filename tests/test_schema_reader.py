"""Schema readers: a consumer reads a few fields of a sample from any source, checked by the
schema's own checks, without touching the sample, and is told which field is wrong."""
import copy
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from viena.common.errors import SampleError
from viena.common.schema import F, FieldError, Invalid, Schema

EXAMPLE = Schema("viena.test.reader/1", {
    "t": F.time, "seq": F.int, "unit": F.str, "v": F.vec(3), "w": F.optional(F.vec(3)),
    "kind": F.enum("A", "B"), "raw": F.struct({"counts": F.vec(2)}),
})
NAMES = ("t", "unit", "v", "w", "kind")
DEFAULTS = {"unit": "u0"}
READ = EXAMPLE.reader(*NAMES, defaults=DEFAULTS)
T = 1_700_000_000_000_000_000


def test_reads_the_named_fields_in_order_and_no_other():
    sample = {"t": T, "unit": "a", "v": [1.0, 2.0, 3.0], "w": None, "kind": "B", "seq": "not read"}
    assert READ(sample) == (T, "a", [1.0, 2.0, 3.0], None, "B")


def test_a_missing_field_takes_its_default_and_an_optional_one_none():
    assert READ({"t": T, "v": [1.0, 2.0, 3.0], "kind": "A"}) == (T, "u0", [1.0, 2.0, 3.0], None, "A")


def test_it_converts_as_decode_does_and_never_changes_the_sample():
    sample = {"t": T, "v": (1, 2, 3), "w": [0, 0.5, 1], "kind": "A"}
    before = copy.deepcopy(sample)
    assert READ(sample) == (T, "u0", [1.0, 2.0, 3.0], [0.0, 0.5, 1.0], "A")
    assert sample == before and type(sample["v"]) is tuple and sample["w"][0] == 0


GOOD = {"t": T, "v": [1.0, 2.0, 3.0], "kind": "A"}


@pytest.mark.parametrize("change, field, not_finite, message", [
    ({"t": None}, "t", False, "t: expected a time"),
    ({"t": 1.7e18}, "t", False, "t: expected a time"),
    ({"v": [1.0, math.nan, 3.0]}, "v", True, "v: expected a finite number"),
    ({"w": [math.inf, 0.0, 0.0]}, "w", True, "w: expected a finite number"),
    ({"v": [1.0, "2", math.nan]}, "v", False, "v: expected a finite number"),   # not only a NaN
    ({"v": [1.0, math.nan]}, "v", False, "v: expected a list of 3"),
    ({"v": [True, 0.0, 0.0]}, "v", False, "v: expected a finite number"),
    ({"unit": None}, "unit", False, "unit: expected text"),       # a default is for a missing field
    ({"kind": "C"}, "kind", False, "kind: expected one of"),
])
def test_a_wrong_field_is_named(change, field, not_finite, message):
    with pytest.raises(FieldError, match=message) as caught:
        READ({**GOOD, **change})
    assert (caught.value.field, caught.value.not_finite) == (field, not_finite)
    assert isinstance(caught.value, SampleError)


def test_a_missing_field_without_default_and_a_non_map_are_named():
    with pytest.raises(FieldError, match="missing field 'v'") as caught:
        READ({"t": T, "kind": "A"})
    assert caught.value.field == "v"
    with pytest.raises(FieldError, match="expected a map"):
        READ([T, "a"])


def test_a_reader_reads_only_the_schemas_fields():
    with pytest.raises(ValueError, match="no field 'x_m'"):
        EXAMPLE.reader("t", "x_m")
    with pytest.raises(ValueError, match="no field 'seq'"):
        EXAMPLE.reader("t", defaults={"seq": 0})                    # a default for a field not read


def expected(sample):
    """What the reader must give: each field through the schema's own check, one by one."""
    if not isinstance(sample, dict):
        return FieldError
    out = []
    for name in NAMES:
        if name not in sample:
            if name in DEFAULTS or name == "w":
                out.append(DEFAULTS.get(name))
                continue
            return FieldError
        try:
            out.append(EXAMPLE.fields[name](copy.deepcopy(sample[name])))
        except Invalid:
            return FieldError
    return tuple(out)


scalars = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**70, 2**70),
                    st.just(T), st.text(max_size=2), st.sampled_from(["A", "B"]), st.none(), st.booleans())
values = st.one_of(scalars, st.lists(scalars, min_size=2, max_size=4),
                   st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=3, max_size=3))
samples = st.one_of(
    st.dictionaries(st.sampled_from([*NAMES, "seq", "other"]), values, max_size=7),
    st.fixed_dictionaries({"t": st.just(T), "v": st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
                           "kind": st.sampled_from(["A", "B"])},
                          optional={"unit": st.text(max_size=3), "w": st.none() | values}),
    scalars,
)


@settings(max_examples=300, deadline=None)
@given(samples)
def test_the_compiled_reader_agrees_with_the_checks_one_by_one(sample):
    want = expected(sample)
    if want is FieldError:
        with pytest.raises(FieldError):
            READ(sample)
    else:
        assert READ(sample) == want
