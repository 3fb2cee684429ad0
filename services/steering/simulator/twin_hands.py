"""The person's hands on the wheel, as the EPOS twin plays them.

After power-up, once the host is talking to the drive and the power stage is off, they turn
the wheel lock to lock and back to the centre, as the calibration procedure asks
(docs/steering.md#power-up-sweep); after that sweep they steer while the motor is free, to
the angle `hands` gives (the sim's route follower). The drive taking the wheel makes them
let go.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from viena.services.steering.simulator.plant import PositionPlant

if TYPE_CHECKING:
    from viena.services.steering.simulator.epos_firmware import TwinSettings

log = logging.getLogger("viena.services.steering.simulator.epos_twin")
#: the longest step a person's hands take at once, however late the twin's thread runs
HAND_STEP_MAX_S = 0.01


class WheelHands:
    """The sweep after power-up, then steering by hand while the drive does not hold the wheel."""

    def __init__(self, settings: TwinSettings, plant: PositionPlant):
        self.settings, self.plant = settings, plant
        #: the wheel angle (rad) the person steers to while the drive does not hold the
        #: wheel, or None (hands off). The sim's route follower.
        self.hands: Callable[[], float | None] | None = None
        self.reset()

    def reset(self) -> None:
        """A new host (or a power-up): it will ask for a new sweep, from the start."""
        self._swept = False
        self._sweep: list[tuple[float, float, float, float]] | None = None   # t0, t1, a, b
        self._sweep_clock = 0.0

    @property
    def sweeping(self) -> bool:
        return self._sweep is not None

    def ask_for_sweep(self) -> bool:
        """The person at the wheel is asked to turn it lock to lock again (the steering
        service restarted its calibration and says so); False if a sweep is under way."""
        if self._sweep is not None:
            return False
        self._swept = False
        return True

    def step(self, dt: float, host_waiting: bool) -> None:
        """The motor free for `dt`: sweep (once the host has waited for it: `host_waiting`)
        or steer."""
        s = self.settings
        if self._sweep is None and s.sweep and not self._swept and host_waiting:
            self._sweep_clock = 0.0
            self._sweep = self._plan_sweep(0.0)
            log.info("EPOS twin: turning the wheel lock to lock for the calibration")
        if self._sweep is None:
            self._drive_by_hand(dt)
            return
        # the hands move with the twin's own steps: a starved host process slows the sweep
        # down rather than making the wheel jump (which the service rightly calls a glitch)
        self._sweep_clock += min(dt, HAND_STEP_MAX_S)
        now = self._sweep_clock
        for t0, t1, a, b in self._sweep:
            if t0 <= now < t1:
                u = (now - t0) / (t1 - t0)
                self.plant.x = a + (b - a) * 0.5 * (1.0 - math.cos(math.pi * u))
                return
            if now < t0:                             # holding against a stop
                self.plant.x = a
                return
        self.plant.x = self._sweep[-1][3]
        self._end_sweep()

    def _end_sweep(self) -> None:
        self._sweep = None
        self._swept = True
        log.info("EPOS twin: sweep done, wheel back at the centre")

    def let_go(self) -> None:
        """The drive takes the wheel: the person lets go. Holding it at the centre after
        a sweep, they are done; in the middle of one, they sweep again when next asked."""
        if self._sweep is not None and self._sweep_clock >= self._sweep[-1][0]:
            self._end_sweep()
        else:
            self._sweep = None

    def _drive_by_hand(self, dt: float) -> None:
        """After the calibration sweep, a person steers while the motor is free."""
        if not self._swept or self.hands is None:
            return
        angle = self.hands()
        if angle is None:
            return
        s = self.settings
        target = math.degrees(angle) / s.slope_deg_per_qc
        step = s.hands_speed_qc_s * min(dt, HAND_STEP_MAX_S)
        self.plant.x += max(-step, min(step, target - self.plant.x))

    def _plan_sweep(self, now: float) -> list[tuple[float, float, float, float]]:
        """Smooth (cosine) moves: to the left stop, hold, to the right stop, hold, centre, hold."""
        s = self.settings
        push = s.lock_qc + 500.0                     # a person pushes against the stop
        points = [self.plant.x, push, -push, 0.0]
        plan, t = [], now
        for a, b in zip(points, points[1:]):
            duration = 0.5 * math.pi * abs(b - a) / s.sweep_speed_qc_s
            plan.append((t, t + duration, a, b))
            t += duration + (s.sweep_hold_s if b != 0.0 else 0.0)
        plan.append((t, t + s.centre_hold_s, 0.0, 0.0))
        return plan
