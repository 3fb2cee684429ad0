"""Sample schemas and their msgpack codec (docs/dataflow.md#samples).

A `Schema` names a sample type (`viena.sim.truth/1`) and lists its fields. `encode` checks
a sample before it goes out, so a bad value is never published; `decode` checks what comes
in and turns anything malformed into a `SampleError` that says which field is wrong.
Every schema lives in the one module that owns it; `SCHEMAS` finds them by name.
A consumer that reads only a few fields, of samples from any source, uses a `Reader`
(`FIX.reader("t", "ecef_m")`): the same checks, on those fields alone.

    >>> FIX = Schema("viena.example/1", {"t": F.time, "seq": F.int, "x_m": F.float})
    >>> FIX.decode(FIX.encode({"t": 1, "seq": 0, "x_m": 2.5}))
    {'t': 1, 'seq': 0, 'x_m': 2.5}
"""
from __future__ import annotations

import builtins
import math
import threading
import weakref
from collections.abc import Callable, Hashable
from typing import Any

import msgpack

from viena.common.errors import SampleError

MSGPACK = "application/msgpack"
#: Bounds on what we unpack: a sample is small; a hostile payload must not eat memory.
_MAX_BYTES = 1 << 20
SCHEMAS: dict[str, Schema] = {}
#: every Reader made, by its schema's name: tests/test_schema_history.py has each read every
#: stored version of its schema (weak: a Reader made for one call is not kept)
READERS: dict[str, weakref.WeakSet[Reader]] = {}

Check = Callable[[Any], Any]


class Invalid(Exception):
    """Raised by a field check; the schema adds where it happened."""

    def __init__(self, what: str, value: Any):
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        super().__init__(f"{what}, got {shown}")


def _finite_float(v) -> float:
    if type(v) is float:
        if v - v == 0.0:                      # fast finite test: inf-inf and nan-nan are nan
            return v
    elif type(v) is int:
        return float(v)
    elif isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    raise Invalid("expected a finite number", v)


def _fast(expr: str, items: str | None = None) -> Callable[[Check], Check]:
    """Attach an inline test for `v` that passes only values a check keeps unchanged (the
    few it turns away take the slow path, which keeps them); schemas compile these into one
    function for the common case (see _Fields). `items`: a test for a list `v` of such
    values, cheaper than testing each (F.list uses it)."""
    def mark(fn: Check) -> Check:
        fn.fast = expr  # type: ignore[attr-defined]  # a mark on the function object, read by getattr
        if items is not None:
            fn.fast_items = items  # type: ignore[attr-defined]  # as above
        return fn
    return mark


#: Names the inline tests use besides `v`: every compiled test's scope has them.
#: `ONLY_STR.issuperset(map(type, v))` tests each item's exact type in C.
_FAST_NAMES = {"ONLY_STR": frozenset([str]), "ONLY_FLOAT": frozenset([float])}

#: `0.0 * x == 0.0` holds for every finite float and fails for NaN and the infinities, so
#: one test on a sum covers all its terms (a sum of finite floats that overflows only
#: takes the slow path).
_fast("type(v) is float and v - v == 0.0",
      items="type(v) is list and ONLY_FLOAT.issuperset(map(type, v)) and 0.0 * sum(v) == 0.0")(_finite_float)


def _made(kind: str, **values: Any) -> Callable[[Check], Check]:
    """Record which F builder made a check and with what (`F.vec(3)`: "vec", n=3), so
    tools that describe a schema in other terms (common/json_schema.py) read it here
    rather than guess it from the function."""
    def mark(fn: Check) -> Check:
        fn.made = (kind, values)  # type: ignore[attr-defined]  # a mark on the function, read by getattr
        return fn
    return mark


class F:
    """Field checks. Each takes a value and returns the value to keep, or raises Invalid."""

    float = staticmethod(_finite_float)

    @staticmethod
    @_fast("type(v) is int and -9223372036854775808 <= v < 18446744073709551616")
    def int(v):
        if type(v) is int and -(1 << 63) <= v < (1 << 64):     # what msgpack can carry
            return v
        raise Invalid("expected a 64-bit integer", v)

    @staticmethod
    @_fast("type(v) is int and 315964800000000000 <= v <= 7258118400000000000")
    def time(v):
        """Absolute time, int ns UTC (between 1980 and 2200)."""
        if type(v) is int and 315_964_800_000_000_000 <= v <= 7_258_118_400_000_000_000:
            return v
        raise Invalid("expected a time in int ns UTC", v)

    @staticmethod
    @_fast("type(v) is str", items="type(v) is list and ONLY_STR.issuperset(map(type, v))")
    def str(v):
        if type(v) is str:
            return v
        raise Invalid("expected text", v)

    @staticmethod
    @_fast("type(v) is bool")
    def bool(v):
        if type(v) is bool:
            return v
        raise Invalid("expected true or false", v)

    @staticmethod
    @_fast("True")
    def any(v):
        return v

    @staticmethod
    @_fast("type(v) is dict and ONLY_STR.issuperset(map(type, v))")
    def map(v):
        if isinstance(v, dict) and all(type(k) is str for k in v):
            return v
        raise Invalid("expected a map with text keys", v)

    @staticmethod
    def vec(n: builtins.int) -> Check:
        """A list of exactly n finite numbers."""
        def check(v):
            if type(v) is list and len(v) == n:
                for x in v:                       # fast path: already finite floats
                    if type(x) is not float or x - x != 0.0:
                        break
                else:
                    return v
            if isinstance(v, (list, tuple)) and len(v) == n:
                return [_finite_float(x) for x in v]
            raise Invalid(f"expected a list of {n} finite numbers", v)
        if 0 < n <= 6:                        # inline: cheaper than two calls for a few terms
            terms = [f"v[{i}]" for i in range(n)]
            items = f"{' is '.join(f'type({x})' for x in terms)} is float and 0.0 * ({' + '.join(terms)}) == 0.0"
        else:
            items = "ONLY_FLOAT.issuperset(map(type, v)) and 0.0 * sum(v) == 0.0"
        check = _made("vec", n=n)(check)
        return _fast(f"type(v) is list and len(v) == {n} and {items}")(check)

    @staticmethod
    def list(item: Check) -> Check:
        def check(v):
            if isinstance(v, (list, tuple)):
                return [item(x) for x in v]
            raise Invalid("expected a list", v)
        check = _made("list", item=item)(check)
        if hasattr(item, "fast_items"):
            return _fast(item.fast_items)(check)
        if hasattr(item, "fast"):           # a list whose items all pass as they are passes as it is
            return _fast(f"type(v) is list and all([({item.fast}) for v in v])")(check)
        return check

    @staticmethod
    def enum(*names: builtins.str) -> Check:
        allowed = frozenset(names)

        def check(v):
            if isinstance(v, Hashable) and v in allowed:
                return v
            raise Invalid(f"expected one of {sorted(allowed)}", v)
        check = _made("enum", allowed=allowed)(check)
        if all(type(name) is builtins.str for name in names):    # a set of literals: one constant
            return _fast(f"type(v) is str and v in {{{', '.join(repr(name) for name in sorted(allowed))}}}")(check)
        return check

    @staticmethod
    def optional(inner: Check) -> Check:
        """May be missing or nil."""
        @_made("optional", inner=inner)
        def check(v):
            return None if v is None else inner(v)
        check.optional = True  # type: ignore[attr-defined]  # a mark on the function, read by getattr
        if hasattr(inner, "fast"):
            return _fast(f"v is None or ({inner.fast})")(check)
        return check

    @staticmethod
    def struct(fields: dict[builtins.str, Check]) -> Check:
        """A nested map with its own fields."""
        inner = _Fields(fields)

        @_made("struct", fields=fields)
        def check(v):
            return inner.check(v, "", strict=False)
        return check


class _Fields:
    def __init__(self, fields: dict[str, Check]):
        self.fields = dict(fields)
        self._items = list(self.fields.items())
        self._keys = frozenset(self.fields)
        self._all_valid = self._compile()

    def _compile(self):
        """One function testing every field inline: True means the sample is valid as it
        is (the usual case, at a fraction of the cost); False means take the slow path,
        which converts what it can and says exactly what is wrong. A required field is read
        with sample[k] (half the cost of .get): a missing one is a KeyError."""
        lines = ["def all_valid(sample):", "    get = sample.get", "    try:"]
        for i, (k, c) in enumerate(self._items):
            expr = getattr(c, "fast", f"C[{i}](v) is v")
            if getattr(c, "optional", False):
                lines.append(f"        v = get({k!r}, M)")
                lines.append(f"        if v is not M and not ({expr}): return False")
            else:
                lines.append(f"        v = sample[{k!r}]")
                lines.append(f"        if not ({expr}): return False")
        lines += ["    except KeyError:", "        return False", "    return True"]
        scope = {**_FAST_NAMES, "M": _MISSING, "C": [c for _, c in self._items]}
        exec("\n".join(lines), scope)
        return scope["all_valid"]

    def check(self, sample: Any, where: str, strict: bool) -> dict:
        """Checks in place (a fresh dict from msgpack, or the caller's own for encode)."""
        if type(sample) is not dict:
            raise SampleError(f"{where}: {Invalid('expected a map', sample)}")
        if strict and not self._keys.issuperset(sample):
            extra = sorted(set(sample) - self._keys, key=str)[0]
            raise SampleError(f"{where}: unknown field {extra!r}")
        try:
            if self._all_valid(sample):
                return sample
        except (Invalid, SampleError):
            pass                                  # the slow path below says what is wrong
        k = None
        try:
            for k, c in self._items:
                v = sample.get(k, _MISSING)
                if v is _MISSING:
                    if getattr(c, "optional", False):
                        continue
                    raise SampleError(f"{where}: missing field '{k}'")
                r = c(v)
                if r is not v:
                    sample[k] = r
        except Invalid as exc:
            raise SampleError(f"{where}.{k}: {exc}") from None
        except SampleError as exc:               # from a nested struct, or missing
            if str(exc).startswith(f"{where}:"):
                raise
            raise SampleError(f"{where}.{k}{exc}") from None
        return sample


_MISSING = object()


class Schema:
    """A named, versioned sample type with checked msgpack encode/decode."""

    def __init__(self, name: str, fields: dict[str, Check]):
        self.name = name
        self._fields = _Fields(fields)
        self.fields = self._fields.fields
        self.encoding = f"{MSGPACK};{name}"
        SCHEMAS[name] = self

    def validate(self, sample: Any, strict: bool = True) -> dict:
        return self._fields.check(sample, self.name, strict)

    def encode(self, sample: dict) -> bytes:
        """Check and pack; raises SampleError rather than publish a bad value."""
        checked = self._fields.check(sample, self.name, True)
        packer = _take_packer()
        try:
            return packer.pack(checked)
        except (OverflowError, TypeError, ValueError) as exc:   # e.g. in an F.any / F.map field
            raise SampleError(f"{self.name}: cannot be packed ({exc})") from None
        finally:
            _packers.packer = packer

    def decode(self, payload: bytes | bytearray | memoryview) -> dict:
        """Unpack and check; unknown fields from newer producers are kept."""
        return self._fields.check(unpack(payload, self.name), self.name, False)

    def __repr__(self) -> str:
        return f"Schema({self.name!r})"

    def reader(self, *names: str, defaults: dict | None = None) -> Reader:
        """Reads these fields out of a sample with this schema's checks (see `Reader`)."""
        return Reader(self, names, defaults)


class FieldError(SampleError):
    """A sample whose field `field` is missing or wrong. `not_finite`: the field held
    numbers of the right shape, one of them NaN or infinite (a consumer may count that
    apart from malformed input)."""

    def __init__(self, message: str, field: str, not_finite: bool = False):
        super().__init__(message)
        self.field, self.not_finite = field, not_finite


class Reader:
    """Some fields of a schema, read out of a sample and checked by the schema's own checks.

    For consumers that read a few fields of samples from any source, not only from
    viena's own publishers (the estimator reads a fix's position and velocity): only these
    fields are checked, a field in `defaults` (or an optional one) may be missing, and
    the sample is never changed. Calling it returns the values in the order of `names`,
    or raises FieldError. Values that pass unchanged are the sample's own objects.
    Cheap: the usual case (every value already valid) is one compiled test per field,
    as in `Schema.decode`.
    """

    def __init__(self, schema: Schema, names, defaults: dict | None = None):
        self.schema, self.names = schema, tuple(names)
        self.defaults = dict(defaults or {})
        unknown = sorted(set(self.names) - set(schema.fields) | set(self.defaults) - set(self.names))
        if unknown:
            raise ValueError(f"{schema.name} has no field {unknown[0]!r} to read")
        self._checks = [schema.fields[n] for n in self.names]
        for name, check in zip(self.names, self._checks):
            if getattr(check, "optional", False):
                self.defaults.setdefault(name, None)
        self._fast = self._compile()
        READERS.setdefault(schema.name, weakref.WeakSet()).add(self)

    def _compile(self):
        """One function: the values when each is what its check keeps, else None (a field
        without a default is read with sample[name], as in _Fields._compile)."""
        lines = ["def fast(sample):", "    if type(sample) is not dict: return None",
                 "    get = sample.get", "    try:"]
        for i, (name, check) in enumerate(zip(self.names, self._checks)):
            expr = getattr(check, "fast", f"C[{i}](v) is v")
            if name in self.defaults:
                lines.append(f"        v{i} = v = get({name!r}, M)")
                lines.append(f"        if v is M: v{i} = D[{i}]")
                lines.append(f"        elif not ({expr}): return None")
            else:
                lines.append(f"        v{i} = v = sample[{name!r}]")
                lines.append(f"        if not ({expr}): return None")
        lines += ["    except KeyError:", "        return None"]
        lines.append(f"    return ({''.join(f'v{i}, ' for i in range(len(self.names)))})")
        scope = {**_FAST_NAMES, "M": _MISSING, "C": self._checks, "D": [self.defaults.get(n) for n in self.names]}
        exec("\n".join(lines), scope)
        return scope["fast"]

    def __call__(self, sample: Any) -> tuple:
        try:
            values = self._fast(sample)
        except (Invalid, SampleError):
            values = None                     # the slow path below says what is wrong
        return self._slow(sample) if values is None else values

    def _slow(self, sample: Any) -> tuple:
        where = self.schema.name
        if not isinstance(sample, dict):
            raise FieldError(f"{where}: {Invalid('expected a map', sample)}", "")
        values = []
        for name, check in zip(self.names, self._checks):
            v = sample.get(name, _MISSING)
            if v is _MISSING:
                if name not in self.defaults:
                    raise FieldError(f"{where}: missing field '{name}'", name)
                values.append(self.defaults[name])
                continue
            try:
                values.append(check(v))
            except Invalid as exc:
                raise FieldError(f"{where}.{name}: {exc}", name, _fails_for_not_finite(check, v)) from None
            except SampleError as exc:         # from a nested struct
                raise FieldError(f"{where}.{name}{exc}", name) from None
        return tuple(values)


def _fails_for_not_finite(check: Check, v: Any) -> bool:
    """True when v would pass `check` with its NaNs and infinities made zeros."""
    def zero(x):
        return 0.0 if isinstance(x, float) and not math.isfinite(x) else x
    stand_in = [zero(x) for x in v] if isinstance(v, (list, tuple)) else zero(v)
    if stand_in is v or (isinstance(v, (list, tuple)) and all(a is b for a, b in zip(stand_in, v))):
        return False                          # nothing was NaN or infinite
    try:
        check(stand_in)
    except (Invalid, SampleError):
        return False
    return True


_packers = threading.local()


def _take_packer() -> msgpack.Packer:
    """This thread's Packer, taken until the caller puts it back: msgpack.packb builds one
    per call; a Packer is not thread-safe (one per thread) and not re-entrant, so an encode
    made while one packs (a __del__, a dict subclass's items()) builds its own. A Packer
    empties its buffer after each pack, or a failed one."""
    packer = getattr(_packers, "packer", None)
    _packers.packer = None
    return packer if packer is not None else msgpack.Packer(use_bin_type=True)


def unpack(payload: bytes | bytearray | memoryview, what: str = "payload") -> Any:
    """msgpack -> Python, with every failure turned into a SampleError."""
    data = bytes(payload)
    if len(data) > _MAX_BYTES:
        raise SampleError(f"{what}: {len(data)} bytes is larger than any sample")
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises many types for garbage: all mean the same here
        raise SampleError(f"{what}: not valid msgpack ({type(exc).__name__}: {exc})") from None


def schema_of(encoding: str | None) -> Schema | None:
    """The registered schema named by a zenoh encoding like 'application/msgpack;viena.x/1'."""
    if not encoding or ";" not in encoding:
        return None
    return SCHEMAS.get(encoding.split(";", 1)[1])
