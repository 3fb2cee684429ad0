"""Magnetometer readings the HMC5843 cannot have meant.

The car's recordings hold about one such frame in 40-150, with a good CRC (the firmware
sent what it read): registers read as 0xFFFF mid-update ([-269, -1, -1], [-254, 193, -1]),
a low byte lost ([-269, 184, -257] where z is -355), bytes shifted ([1534, -4096, -19458]).
A car cannot turn the Earth's field by a tenth of its size in one 12 ms frame, and the
field's size is known, so a reading is accepted only if it is near the last good one and
of a plausible size. If the field really moves (a calibration change, parking next to a
steel wall), readings that agree with each other for a few frames become the new normal.
"""
from __future__ import annotations

import math

#: |Lisbon field| ([-1121.5, 26479.8, -34884.7] nT ENU, docs/frames.md#magnetic-field-in-lisbon)
LISBON_FIELD_T = 43.81e-6


class MagGlitchFilter:
    def __init__(self, field_T: float = LISBON_FIELD_T, max_jump: float = 0.1,
                 size_range: tuple[float, float] = (0.3, 3.0), settle_frames: int = 5):
        self.jump_T = max_jump * field_T
        self.min_T, self.max_T = size_range[0] * field_T, size_range[1] * field_T
        self.settle_frames = settle_frames
        self._last: list[float] | None = None        # last accepted reading
        self._candidate: list[float] | None = None   # a run of rejected readings that agree
        self._run = 0
        self.rejected = 0

    def reset(self) -> None:
        self._last = self._candidate = None
        self._run = 0

    def accept(self, m_T) -> bool:
        size = math.sqrt(m_T[0] ** 2 + m_T[1] ** 2 + m_T[2] ** 2)
        if not self.min_T <= size <= self.max_T:
            self.rejected += 1
            return False
        if self._last is None or self._near(m_T, self._last):
            self._last = list(m_T)
            self._run = 0
            return True
        if self._candidate is not None and self._near(m_T, self._candidate):
            self._run += 1
        else:
            self._run = 1
        self._candidate = list(m_T)
        if self._run >= self.settle_frames:
            self._last = list(m_T)
            self._run = 0
            return True
        self.rejected += 1
        return False

    def _near(self, a, b) -> bool:
        return (a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2 <= self.jump_T ** 2
