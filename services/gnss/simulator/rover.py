"""A receiver's differential side, as its solver asks it each epoch: the bases it has read
(their positions, for the baseline to its own antenna), its solution's state (rtk.py) and
the errors of that solution (differential.py). The twin tells it what it read on its ports,
on the receiver's GPS time; the solver asks it what each epoch is.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from viena.services.gnss.driver.novatel.enums import PositionType

from .differential import DifferentialErrors
from .errors import GnssErrorModel
from .rtk import DEFAULT_FIGURES, NONE_STATUS, RT2, SINGLE_STATUS, RtkFigures, RtkMachine, RtkStatus

WEEK_MS = 604_800_000
#: how many correction ages the receiver keeps (an hour of 1 Hz observables)
AGES_KEPT = 3600


@dataclass(frozen=True)
class DifferentialFix:
    """What one differential epoch changes in a solution."""

    pos_type: PositionType
    error_enu_m: np.ndarray
    sigma_enu_m: tuple
    diff_age_s: float
    station_id: str
    rtk: bool                   # carrier-phase: the satellites above the RTK mask are counted


def epoch_ms_of_tow(tow_ms: int, now_gps_ms: int) -> int:
    """A time of week (ms) as GPS ms: in the receiver's week, or the next or last when
    closer (an epoch read just after a week's rollover)."""
    epoch = now_gps_ms - now_gps_ms % WEEK_MS + tow_ms
    if epoch - now_gps_ms > WEEK_MS // 2:
        epoch -= WEEK_MS
    elif now_gps_ms - epoch > WEEK_MS // 2:
        epoch += WEEK_MS
    return epoch


class Rover:
    """The corrections a receiver has read, and what they make of each epoch's solution."""

    def __init__(self, errors: GnssErrorModel, engine: str = RT2, *, seed: int = 0,
                 figures: RtkFigures = DEFAULT_FIGURES):
        self.machine = RtkMachine(engine, seed=seed, figures=figures)
        self.errors = DifferentialErrors(errors, seed=seed, engine=engine)
        self.bases: dict[str, tuple] = {}           # base ID -> its ARP, ECEF m
        self._base_id: str | None = None            # the base of the latest observables
        self.correction_ages_s: deque[float] = deque(maxlen=AGES_KEPT)
        self.status: RtkStatus = SINGLE_STATUS      # the latest epoch's

    @property
    def engine(self) -> str:
        return self.machine.engine

    def base_position(self, gps_ms: int, base_id: str, ecef_m) -> None:
        self.bases[base_id] = tuple(float(v) for v in ecef_m)
        self.machine.base_position(gps_ms / 1000.0, base_id)

    def observe(self, gps_ms: int, tow_ms: int, base_id: str, l2: bool) -> None:
        """Observables read at `gps_ms` (the receiver's GPS time) for the base's epoch `tow_ms`."""
        epoch = epoch_ms_of_tow(tow_ms, gps_ms)
        self.correction_ages_s.append((gps_ms - epoch) / 1000.0)
        self._base_id = base_id
        self.machine.observe(gps_ms / 1000.0, epoch / 1000.0, base_id, l2)

    def lose_lock(self, gps_ms: int) -> None:
        """An epoch without a fix (too few satellites)."""
        self.status = self.machine.at(gps_ms / 1000.0, outage=True)
        self.errors.step(NONE_STATUS, gps_ms, None)

    def baseline_m(self, antenna_ecef) -> float:
        base = self.bases.get(self._base_id) if self._base_id is not None else None
        if base is None:
            return 0.0
        return math.dist(base, antenna_ecef)

    def solve(self, gps_ms: int, antenna_ecef, single_error: np.ndarray) -> DifferentialFix | None:
        """This epoch's differential solution, or None when it is the receiver's own."""
        status = self.status = self.machine.at(gps_ms / 1000.0, baseline_m=self.baseline_m(antenna_ecef))
        if status.pos_type is None:
            self.errors.step(status, gps_ms, single_error)
            return None
        error, sigma = self.errors.step(status, gps_ms, single_error)
        return DifferentialFix(status.pos_type, error, sigma, status.diff_age_s, status.base_id,
                               status.phase in ("float", "fixed"))
