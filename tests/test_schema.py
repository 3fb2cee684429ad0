"""Sample schemas: round trips, and every kind of bad input is a SampleError with a message."""
import math

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from viena.common.errors import SampleError
from viena.common.samples.health import HEALTH
from viena.common.samples.truth import TRUTH
from viena.common.schema import F, Schema, schema_of
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import truth_sample

EXAMPLE = Schema("viena.test.example/1", {
    "t": F.time, "seq": F.int, "x_m": F.float, "v": F.vec(3), "name": F.str,
    "ok": F.bool, "kind": F.enum("A", "B"), "note": F.optional(F.str),
    "raw": F.struct({"counts": F.vec(2)}),
})
GOOD = {"t": 1_700_000_000_000_000_000, "seq": 3, "x_m": 1.5, "v": [1.0, 2.0, 3.0],
        "name": "gnss0", "ok": True, "kind": "A", "raw": {"counts": [1.0, 2.0]}}


def test_round_trip_keeps_float64():
    sample = dict(GOOD, x_m=4918490.531999923)
    assert EXAMPLE.decode(EXAMPLE.encode(dict(sample))) == sample


def test_truth_round_trip():
    car = SimCar()
    for _ in range(50):
        truth = car.step(0.01)
    sample = truth_sample(truth)
    back = TRUTH.decode(TRUTH.encode(dict(sample)))
    assert back["ecef_m"] == sample["ecef_m"]          # float64 survives: no 0.5 m loss
    assert schema_of(TRUTH.encoding) is TRUTH


@pytest.mark.parametrize("change, message", [
    ({"x_m": float("nan")}, "x_m: expected a finite number"),
    ({"x_m": float("inf")}, "x_m: expected a finite number"),
    ({"x_m": "1.0"}, "x_m: expected a finite number"),
    ({"x_m": True}, "x_m: expected a finite number"),
    ({"seq": 1.5}, "seq: expected a 64-bit integer"),
    ({"seq": 2**70}, "seq: expected a 64-bit integer"),
    ({"t": -5}, "t: expected a time"),
    ({"v": [1.0, 2.0]}, "v: expected a list of 3"),
    ({"v": [1.0, float("-inf"), 2.0]}, "v: expected a finite number"),
    ({"kind": "C"}, "kind: expected one of"),
    ({"kind": ["A"]}, "kind: expected one of"),              # unhashable: a reason, not a TypeError
    ({"kind": {"A": 1}}, "kind: expected one of"),
    ({"raw": {"counts": [1.0]}}, "raw.counts: expected a list of 2"),
    ({"raw": {}}, "raw: missing field 'counts'"),
    ({"surprise": 1}, "unknown field 'surprise'"),
])
def test_encode_rejects_with_a_message(change, message):
    with pytest.raises(SampleError, match=message.replace("(", r"\(")):
        EXAMPLE.encode(dict(GOOD, **change))


def test_missing_field_is_named():
    sample = dict(GOOD)
    del sample["seq"]
    with pytest.raises(SampleError, match="missing field 'seq'"):
        EXAMPLE.decode(msgpack.packb(sample))


def test_optional_field_may_be_nil_or_absent():
    assert EXAMPLE.decode(EXAMPLE.encode(dict(GOOD, note=None)))["note"] is None
    assert "note" not in EXAMPLE.decode(EXAMPLE.encode(dict(GOOD)))


def test_decode_keeps_unknown_fields_of_newer_producers():
    payload = msgpack.packb(dict(GOOD, added_later=1))
    assert EXAMPLE.decode(payload)["added_later"] == 1


@pytest.mark.parametrize("payload", [b"", b"\xc1", b"\x93\x01\x02\x03", b"\x81\xa1a",
                                     msgpack.packb([1, 2]), msgpack.packb({1: 2}), b"{not json"])
def test_garbage_is_a_sample_error(payload):
    with pytest.raises(SampleError):
        EXAMPLE.decode(payload)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_never_crash(payload):
    try:
        EXAMPLE.decode(payload)
    except SampleError as exc:
        assert str(exc)
    try:
        HEALTH.decode(payload)
    except SampleError:
        pass


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(2**63), max_value=2**64 - 1) | st.floats() | st.text(max_size=5),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=4), children, max_size=4),
    max_leaves=12)


@pytest.mark.slow  # 300 random maps
@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(GOOD) + ["x"]), json_values, max_size=10))
def test_random_maps_are_accepted_only_when_valid(sample):
    """Whatever a random producer packs, decode either returns a sample that passes every
    check, or raises a SampleError; never anything else, never a NaN."""
    try:
        out = EXAMPLE.decode(msgpack.packb(sample))
    except SampleError:
        return
    assert math.isfinite(out["x_m"]) and all(math.isfinite(v) for v in out["v"])
    assert isinstance(out["seq"], int) and out["kind"] in ("A", "B")


@settings(max_examples=200, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False), st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=3, max_size=3),
       st.integers(min_value=0, max_value=2**63 - 1), st.text())
def test_valid_samples_round_trip(x, v, seq, name):
    sample = dict(GOOD, x_m=x, v=v, seq=seq, name=name)
    assert EXAMPLE.decode(EXAMPLE.encode(dict(sample))) == sample


INLINE = Schema("viena.test.inline/1", {
    "v": F.vec(3), "big": F.vec(9), "floats": F.list(F.float), "names": F.list(F.str), "counts": F.map,
    "maybe": F.optional(F.vec(2)),
})


def _inline_sample(**change):
    sample = {"v": [1.0, 2.0, 3.0], "big": [float(i) for i in range(9)], "floats": [0.5, -0.5],
              "names": ["gnss0"], "counts": {"imu": 1}}
    return dict(sample, **change)


@pytest.mark.parametrize("change", [
    {"v": [1e308, 1e308, -1e308]},                 # finite, though their sum overflows
    {"big": [1e308] * 9}, {"floats": [1.7e308, 1.7e308]}, {"floats": []},
    {"names": []}, {"counts": {}}, {"maybe": None}, {"maybe": [-0.0, 5e-324]},
])
def test_the_inline_test_takes_what_its_check_keeps(change):
    """The compiled test may send a valid sample to the slow path (a sum that overflows);
    either way the sample passes unchanged, in the same bytes."""
    sample = _inline_sample(**change)
    before = {k: list(v) if isinstance(v, list) else v for k, v in sample.items()}
    payload = INLINE.encode(sample)
    assert payload == msgpack.packb(before, use_bin_type=True)
    assert INLINE.decode(payload) == before


@pytest.mark.parametrize("change, message", [
    ({"v": [1.0, float("nan"), 3.0]}, "v: expected a finite number"),
    ({"v": [float("inf"), float("-inf"), 3.0]}, "v: expected a finite number"),
    ({"big": [0.0] * 8 + [float("nan")]}, "big: expected a finite number"),
    ({"floats": [1.0, float("inf")]}, "floats: expected a finite number"),
    ({"names": ["gnss0", 1]}, "names: expected text"),
    ({"counts": {"imu": 1, 2: 3}}, "counts: expected a map with text keys"),
    ({"maybe": [1.0, float("nan")]}, "maybe: expected a finite number"),
])
def test_the_inline_test_turns_away_what_its_check_rejects(change, message):
    with pytest.raises(SampleError, match=message):
        INLINE.encode(_inline_sample(**change))


def test_whole_numbers_in_a_vec_become_floats():
    sample = _inline_sample(v=[1, 2.0, 3], floats=[1, 2])
    assert msgpack.unpackb(INLINE.encode(sample))["v"] == [1.0, 2.0, 3.0]
    assert [type(x) for x in sample["floats"]] == [float, float]


def test_encode_packs_as_packb_does():
    sample = dict(GOOD, x_m=4918490.531999923)
    assert EXAMPLE.encode(dict(sample)) == msgpack.packb(sample, use_bin_type=True)
    with pytest.raises(SampleError, match="cannot be packed"):
        HEALTH.encode(dict(HEALTH.decode(HEALTH.encode(_health())), state={"x": object()}))
    assert HEALTH.encode(_health()) == msgpack.packb(_health(), use_bin_type=True)   # a failed pack left nothing behind


def _health():
    return {"t": 1_700_000_000_000_000_000, "seq": 1, "service": "sim", "uptime_s": 1.0,
            "rates_hz": {}, "counts": {}, "errors": {}}


def test_an_encode_made_while_another_packs_gives_both_their_bytes():
    """A Packer is not re-entrant: an encode run from inside another's pack (a dict
    subclass's items(), a __del__) must not share it."""
    inner = Schema("viena.test.reentrant.inner/1", {"a": F.any})

    class Sneaky(dict):
        def items(self):
            self.inner_bytes = inner.encode({"a": 7})
            return super().items()

    outer = Schema("viena.test.reentrant.outer/1", {"a": F.any})
    value = Sneaky(k=1)
    assert outer.encode({"a": value}) == msgpack.packb({"a": {"k": 1}}, use_bin_type=True)
    assert value.inner_bytes == msgpack.packb({"a": 7}, use_bin_type=True)
