"""How a sample reads to a person: the text pieces a schema module's `monitor_view` is made of.

Each module that owns a schema says how the monitor shows its samples, with a function
`monitor_view(sample) -> {column: text}`; the monitor lays out whatever it is given.
A sample on the wire may come from any source and carry any value, so every function
here takes anything and never raises: a value that is not what it should be reads "-".

    >>> fmt_vec([0.1, 9.81, 0.0])
    '[0.10 9.81 0.00]'
    >>> fields_view({"t": 1, "armed": False, "angle_rad": 0.1})
    {'armed': 'no', 'angle °': '5.73'}
"""
from __future__ import annotations

import math

#: corrections older than this read as stale (red): the receiver is about to fall back to a
#: coarser solution (the fixes' diff age, the NTRIP client's last message)
CORRECTIONS_STALE_S = 10.0


class Alert(str):
    """Text that asks to be noticed (the monitor shows it in red)."""

    __slots__ = ()


def number(v) -> float | None:
    """A finite real number as a float, else None (bools are not numbers here)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def vector(v, n: int | None = None) -> list[float] | None:
    """A non-empty list of finite numbers (of length n if given), else None."""
    if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n) or not v:
        return None
    out = []
    for x in v:
        if (f := number(x)) is None:
            return None
        out.append(f)
    return out


def norm(v, n: int | None = None) -> float | None:
    """The length of a vector, or None."""
    vec = vector(v, n)
    return None if vec is None else math.sqrt(sum(x * x for x in vec))


def fmt_age(age: float | None) -> str:
    """A duration: to the hundredth below 10 s, whole seconds below 2 min, then minutes."""
    if age is None:
        return "-"
    if age < 10:
        return f"{age:.2f} s"
    if age < 120:
        return f"{age:.0f} s"
    return f"{age / 60:.0f} min"


def fmt_num(v, digits: int = 3) -> str:
    """A scalar for a cell: ints as they are, floats to `digits` places, None as '-'."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.{digits}f}" if v == 0 or 1e-3 <= abs(v) < 1e6 else f"{v:.{digits}g}"
    return str(v)[:40] or "-"


def fmt_unit(v, unit: str, digits: int = 2, scale: float = 1.0) -> str:
    """A number with its unit ('3.20 m/s'), or '-'."""
    n = number(v)
    return "-" if n is None else f"{n * scale:.{digits}f} {unit}"


def fmt_vec(v, digits: int = 2, scale: float = 1.0) -> str:
    vec = vector(v)
    if vec is None:
        return "-"
    return "[" + " ".join(f"{x * scale:.{digits}f}" for x in vec) + "]"


def fmt_deg(rad) -> str:
    """An angle given in rad, shown in degrees."""
    n = number(rad)
    return "-" if n is None else f"{math.degrees(n):.1f}°"


def fmt_map(values, digits: int = 1, limit: int = 6) -> str:
    """A map on one line, its first `limit` entries."""
    if not isinstance(values, dict):
        return "-"
    items = [f"{k} {fmt_num(v, digits)}" for k, v in list(values.items())[:limit]]
    if len(values) > limit:
        items.append(f"+{len(values) - limit}")
    return ", ".join(items) or "-"


def fields_view(sample, first=(), skip=("t", "seq")) -> dict[str, str]:
    """Any sample's top-level fields, the names in `first` first: angles in degrees, maps
    on one line. For samples with many fields that all matter (the steering state)."""
    if not isinstance(sample, dict):
        return {}
    names = [k for k in first if k in sample] + [k for k in sample if k not in first and k not in skip]
    cells = {}
    for name in names:
        v = sample[name]
        if isinstance(name, str) and name.endswith("_rad") and number(v) is not None:
            cells[name[:-4] + " °"] = f"{math.degrees(v):.2f}"
        elif isinstance(v, dict):
            cells[str(name)] = fmt_map(v, 2) if v else "-"
        elif isinstance(v, (list, tuple)):
            cells[str(name)] = fmt_vec(v, 3) if vector(v) else (", ".join(map(str, v))[:40] or "-")
        else:
            cells[str(name)] = fmt_num(v)
    return cells


def fields_line(sample, limit: int = 3) -> str:
    """The first few of `fields_view` on one line ('connected yes, port ... +2')."""
    cells = list(fields_view(sample).items())
    text = ", ".join(f"{k} {v}" for k, v in cells[:limit])
    return (text + (f" +{len(cells) - limit}" if len(cells) > limit else "")) or "-"
