"""Key expressions: everything the car says lives under viena/<car>/ (docs/dataflow.md#key-expressions).

What each key is (its pattern, schema, producer, rate) is declared once, in the table of
topics (common/samples/topics.py); `Keys` puts a car's prefix before it:

    >>> Keys("elettra").of(topics.GNSS_FIX, unit="gnss0")
    'viena/elettra/gnss/gnss0/fix'
"""
from __future__ import annotations

from viena.common.samples.topics import ALIVE, HEALTH, ROOT, SIM_TRUTH, Topic, topic_of

__all__ = ["DEFAULT_CAR", "ROOT", "Keys"]

DEFAULT_CAR = "elettra"


class Keys:
    """Builds key expressions for one car."""

    def __init__(self, car: str = DEFAULT_CAR):
        if not car or any(c in car for c in "/*$?#"):
            raise ValueError(f"car name {car!r} must be a single key chunk (no / * $ ? #)")
        self.car = car
        self.prefix = f"{ROOT}/{car}"

    def of(self, topic: Topic, **chunks: str | None) -> str:
        """The key of `topic` on this car; a placeholder not given is any chunk (`*`)."""
        return f"{self.prefix}/{topic.key(**chunks)}"

    def key(self, *parts: str | None) -> str:
        """The key of parts given as text (a setting such as the estimator's `gnss_key`, a
        scenario's target; None parts left out). The car's own code names topics, with `of`."""
        return "/".join([self.prefix, *(str(p) for p in parts if p)])

    def local(self, key: str) -> str | None:
        """`key` after viena/<car>/, or None when it is not this car's."""
        prefix = self.prefix + "/"
        return key[len(prefix):] if key.startswith(prefix) else None

    def topic_of(self, key: str):
        """(topic, placeholders) of one of this car's keys; None for a key the table does not know."""
        local = self.local(key)
        return None if local is None else topic_of(local)

    def health(self, service: str, unit: str | None = None) -> str:
        return self.of(HEALTH, service=service, unit=unit)

    def alive(self, service: str | None = None, unit: str | None = None) -> str:
        """Liveliness token of a running process (for discovery and display only); with no
        service, every token's key (`alive/**`)."""
        if service is None:
            return self.of(ALIVE, service="**", unit=None)
        return self.of(ALIVE, service=service, unit=unit)

    @property
    def all(self) -> str:
        return f"{self.prefix}/**"

    @property
    def truth(self) -> str:
        return self.of(SIM_TRUTH)

    def __repr__(self) -> str:
        return f"Keys({self.car!r})"
