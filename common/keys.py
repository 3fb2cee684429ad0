"""Key expressions: everything the car says lives under viena/<car>/ (docs/dataflow.md#key-expressions)."""
from __future__ import annotations

DEFAULT_CAR = "elettra"
ROOT = "viena"


class Keys:
    """Builds key expressions for one car: Keys("elettra").key("gnss", "gnss0", "fix")."""

    def __init__(self, car: str = DEFAULT_CAR):
        if not car or any(c in car for c in "/*$?#"):
            raise ValueError(f"car name {car!r} must be a single key chunk (no / * $ ? #)")
        self.car = car
        self.prefix = f"{ROOT}/{car}"

    def key(self, *parts: str | None) -> str:
        return "/".join([self.prefix, *(str(p) for p in parts if p)])

    def health(self, service: str, unit: str | None = None) -> str:
        return self.key(service, unit, "health")

    def alive(self, service: str, unit: str | None = None) -> str:
        """Liveliness token of a running process: for discovery and display only."""
        return self.key("alive", service, unit)

    @property
    def all(self) -> str:
        return f"{self.prefix}/**"

    @property
    def truth(self) -> str:
        return self.key("sim", "truth")

    def __repr__(self) -> str:
        return f"Keys({self.car!r})"
