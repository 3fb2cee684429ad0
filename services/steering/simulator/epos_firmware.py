"""The EPOS firmware as the twin plays it: the DS402 state machine read from its table
(model/ds402.py: TRANSITIONS, FAULT_FROM, EPOS_STATUSWORD), the axis in Position Mode (the
fitted `plant.PositionPlant`, within the software position limits), the faults and their
EMCY, and the objects it computes when read. `epos_twin.EposTwin` is this on a CANopen node.
"""
from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import canopen

from viena.common import clock as clocks
from viena.services.steering.driver.emcy import (
    ERROR_REGISTER,
    FOLLOWING_ERROR,
    LIFE_GUARD_ERROR,
    SOFTWARE_POSITION_LIMIT_ERROR,
    emcy_name,
)
from viena.services.steering.model import ds402
from viena.services.steering.model.calibration import SLOPE_DEG_PER_QC
from viena.services.steering.model.drive import EDS_PATH, POSITION_MODE
from viena.services.steering.simulator.plant import TRAJ01, PlantParams, PositionPlant
from viena.services.steering.simulator.twin_hands import WheelHands
from viena.services.steering.simulator.twin_heartbeat import HostHeartbeat
from viena.services.steering.simulator.twin_pdos import Readers, TwinPdos

log = logging.getLogger("viena.services.steering.simulator.epos_twin")     # the twin's log

INDEX_PROCESSING_ERROR = 0xFF02


@dataclass
class TwinSettings:
    node_id: int = 1
    #: the mechanical stops, in encoder counts from the true straight-ahead position; the
    #: car's sweeps measured ~95 000 qc lock to lock
    lock_qc: float = 47_600.0
    #: where the wheel stands at power-up (counts from straight ahead): the encoder's zero
    power_up_qc: float = 1_500.0
    slope_deg_per_qc: float = SLOPE_DEG_PER_QC
    #: the person's lock-to-lock sweep after power-up
    sweep: bool = True
    sweep_speed_qc_s: float = 60_000.0
    sweep_delay_s: float = 0.5
    sweep_hold_s: float = 0.3
    #: asked to bring the wheel back to the centre, a person holds it there a moment: the
    #: steering takes a sweep once the wheel has stood still (sweep_settle_s, 0.5 s)
    centre_hold_s: float = 1.5
    #: how fast the person's hands turn the wheel when they drive (the motor free)
    hands_speed_qc_s: float = 40_000.0
    quickstop_decel_qc_s2: float = 400_000.0
    plant: PlantParams = field(default_factory=lambda: TRAJ01)
    #: how often the twin steps by itself; a SYNC, an RPDO and a controlword step it too, at
    #: their moment, so this is the person's hands, the sweep and the supervision's grain
    step_period_s: float = 0.01

class EposFirmware:
    """What the EPOS firmware does on one node: its DS402 states, its motion, its faults and
    the values it computes; `epos_twin.EposTwin` puts it on a CANopen network."""

    def __init__(self, network: canopen.Network, settings: TwinSettings | None = None,
                 clock: Callable[[], float] = clocks.monotonic, eds: str = str(EDS_PATH)):
        self.network = network
        self.settings = s = settings or TwinSettings()
        self._clock = clock
        self._eds = eds
        self._lock = threading.RLock()
        self._stop = clocks.Event()
        self._thread: Any = None
        self.node: canopen.LocalNode | None = None
        self.plant = PositionPlant(s.plant, s.power_up_qc)
        self.powered = False
        self.emcy_sent: list[int] = []
        self._hb_subscribed: int | None = None
        self._sync_subscribed: int | None = None
        #: the person at the wheel (`person.hands`: the sim's route follower)
        self.person = WheelHands(s, self.plant)
        self.host_hb = HostHeartbeat()
        #: the objects the firmware computes when read (index -> value at a subindex)
        self._readers: Readers = {
            0x6041: lambda sub: self.statusword,
            0x6064: lambda sub: self.position_qc,
            0x6062: lambda sub: self._demand_qc(),
            0x20F4: lambda sub: max(-32768, min(32767, round(self.plant.demand - self.plant.x))),
            0x6061: lambda sub: self.op_mode,
            0x2020: lambda sub: self.position_qc & 0xFFFF,
            0x1001: lambda sub: self._error_register(),
            0x1003: self._history_entry,
        }
        self.pdos = TwinPdos(network, self._readers)

    # -- power-up ----------------------------------------------------------------------------
    def _boot_state(self) -> None:
        now = self._clock()
        self.state = ds402.SWITCH_ON_DISABLED
        self.controlword = 0
        self.setting_qc = 0
        self.op_mode = 1                          # EDS default: profile position
        self.limits = (-(2 ** 31), 2 ** 31 - 1)
        self.max_following_error = 2000           # firmware default
        self.sensor_type, self.sensor_polarity = 1, 0
        self.errors: list[int] = []
        self.history: list[int] = []
        self.encoder_offset = round(self.plant.x)
        self.plant.coast(0.0)
        self._stop_target = self.plant.x
        self._reaction_until = 0.0
        self.host_hb.reset()
        self.pdos.reset()
        self._last_step = now
        self.person.reset()
    # -- what the car and tests read ------------------------------------------------------
    @property
    def physical_qc(self) -> float:
        """Wheel position in counts from straight ahead (what the laser fit measures)."""
        return self.plant.x

    @property
    def position_qc(self) -> int:
        """The drive's position actual value 0x6064."""
        raw = round(self.plant.x) - self.encoder_offset
        return -raw if self.sensor_polarity & 1 else raw

    @property
    def true_zero_qc(self) -> int:
        """Where straight ahead is on this power-up's encoder counter (the ideal zeroRef)."""
        return -self.encoder_offset

    def wheel_angle_rad(self) -> float:
        """The bicycle model's wheel angle (positive left) for the simulated car."""
        return math.radians(self.settings.slope_deg_per_qc * self.plant.x)

    @property
    def _live(self) -> canopen.LocalNode:
        """The node, made by the first power-up."""
        if self.node is not None:
            return self.node
        raise RuntimeError("the EPOS twin was never powered on")

    @property
    def statusword(self) -> int:
        sw = ds402.EPOS_STATUSWORD[self.state]
        if self.node is not None and self.node.nmt.state == "OPERATIONAL":
            sw |= ds402.SW_REMOTE
        if FOLLOWING_ERROR in self.errors:
            sw |= ds402.SW_FOLLOWING_ERROR
        if self.state == ds402.OPERATION_ENABLED and abs(self.plant.demand - self.plant.x) < 100:
            sw |= ds402.SW_TARGET_REACHED
        return sw

    @property
    def sweeping(self) -> bool:
        return self.person.sweeping

    def ask_for_sweep(self) -> bool:
        """The person is asked to sweep again (`WheelHands.ask_for_sweep`)."""
        return self.person.ask_for_sweep()

    def inject_error(self, code: int) -> None:
        """A device error as the hardware would raise it (over temperature, ...)."""
        with self._lock:
            self._fault(code, self._clock())

    # -- time -----------------------------------------------------------------------------
    def step(self, now: float | None = None) -> None:
        with self._lock:
            if not self.powered:
                return
            now = self._clock() if now is None else now
            dt = max(0.0, now - self._last_step)
            self._last_step = now
            self._move(dt, now)
            self._supervise(now)
            self.pdos.on_change(self._live)

    def _move(self, dt: float, now: float) -> None:
        p, s = self.plant, self.settings
        if self.state == ds402.OPERATION_ENABLED:
            demand = self._to_physical(self.setting_qc) if self.op_mode == POSITION_MODE else p.demand
            lo, hi = self.limits
            lo_phys, hi_phys = self._to_physical(lo), self._to_physical(hi)
            p.step(min(max(demand, min(lo_phys, hi_phys)), max(lo_phys, hi_phys)), dt)
        elif self.state in (ds402.QUICK_STOP_ACTIVE, ds402.FAULT_REACTION):
            p.step(self._stop_target, dt)
            if self.state == ds402.FAULT_REACTION and now >= self._reaction_until:
                self.state = ds402.FAULT
                p.coast(0.0)
        else:
            p.coast(dt)
            seen = self.host_hb.seen_s
            self.person.step(dt, seen is not None and self._live.nmt.state == "OPERATIONAL"
                             and now - seen >= s.sweep_delay_s)
        if abs(p.x) > s.lock_qc:                         # the mechanical stop
            p.x = math.copysign(s.lock_qc, p.x)
            p.v = 0.0

    def _to_physical(self, counter_qc: int) -> float:
        """A position-counter value as counts from straight ahead (limits are in counter qc)."""
        if counter_qc in (-(2 ** 31), 2 ** 31 - 1):
            return math.copysign(1e12, counter_qc)
        raw = -counter_qc if self.sensor_polarity & 1 else counter_qc
        return raw + self.encoder_offset

    def _supervise(self, now: float) -> None:
        p = self.plant
        if self.state in (ds402.OPERATION_ENABLED, ds402.QUICK_STOP_ACTIVE):
            if abs(p.demand - p.x) > self.max_following_error:
                self._fault(FOLLOWING_ERROR, now)
            elif self.state == ds402.OPERATION_ENABLED:
                lo, hi = self.limits
                if not lo <= self.position_qc <= hi:
                    self._fault(SOFTWARE_POSITION_LIMIT_ERROR, now)
        if self.host_hb.lost(now) and self.host_hb.seen_s is not None:
            log.warning("EPOS twin: host heartbeat lost")
            self.host_hb.seen_s = None
            if LIFE_GUARD_ERROR not in self.errors:
                self._fault(LIFE_GUARD_ERROR, now)

    # -- faults ---------------------------------------------------------------------------
    def _fault(self, code: int, now: float) -> None:
        if code not in self.errors:
            self.errors.append(code)
            self.history.insert(0, code)
            del self.history[5:]
        log.info("EPOS twin fault: 0x%04X %s in %s", code, emcy_name(code), self.state)
        self.emcy_sent.append(code)
        if self._live.nmt.state != "STOPPED":
            self._live.emcy.send(code, self._error_register())
        p = self.plant
        if ds402.FAULT_FROM.get(self.state) == ds402.FAULT_REACTION:
            dec = self.settings.quickstop_decel_qc_s2
            self._stop_target = p.x + p.v * abs(p.v) / (2.0 * dec)
            self._reaction_until = now + max(abs(p.v) / dec, 0.02)
            self.state = ds402.FAULT_REACTION
        elif self.state != ds402.FAULT_REACTION:
            self.state = ds402.FAULT
            p.coast(0.0)

    def _error_register(self) -> int:
        reg = 0
        for code in self.errors:
            reg |= ERROR_REGISTER.get(code, 0x01)
        return reg | (0x01 if self.errors else 0)

    def _try_fault_reset(self, now: float) -> None:
        persisting = []
        for code in self.errors:
            if code == LIFE_GUARD_ERROR and self.host_hb.lost(now):
                persisting.append(code)
            elif code == SOFTWARE_POSITION_LIMIT_ERROR and not self.limits[0] <= self.position_qc <= self.limits[1]:
                persisting.append(code)
        self.errors = persisting
        if persisting:
            log.info("EPOS twin: fault reset refused, %s persists", emcy_name(persisting[0]))
            return
        self.state = ds402.SWITCH_ON_DISABLED
        self._live.emcy.reset(0)
        log.info("EPOS twin: fault reset")

    # -- DS402 ----------------------------------------------------------------------------
    def _on_controlword(self, cw: int) -> None:
        previous, self.controlword = self.controlword, cw
        now = self._clock()
        # (an RPDO has just stepped the twin: stepping again at the same instant changes
        # nothing but asks the person's hands once more, and the sim's route follower's
        # path depends on how often it is asked: kept, for the same sim)
        self.step(now)
        new = ds402.next_state(self.state, ds402.command_of(cw, previous))
        if new == self.state:
            return
        if self.state == ds402.FAULT:             # only a fault reset leaves it, if no error persists
            self._try_fault_reset(now)
        else:
            self._enter(new, now)

    def _enter(self, new: str, now: float) -> None:
        p = self.plant
        if new == ds402.OPERATION_ENABLED and self.state != ds402.QUICK_STOP_ACTIVE:
            p.reset(p.x)
            self.person.let_go()
        elif new == ds402.QUICK_STOP_ACTIVE:
            dec = self.settings.quickstop_decel_qc_s2
            self._stop_target = p.x + p.v * abs(p.v) / (2.0 * dec)
        elif new in ds402.POWER_STAGE_OFF:
            p.coast(0.0)
        log.debug("EPOS twin: %s -> %s", self.state, new)
        self.state = new
        if new == ds402.OPERATION_ENABLED and self.sensor_type == 1:
            self._fault(INDEX_PROCESSING_ERROR, now)   # the encoder's index track is damaged

    # -- object dictionary ----------------------------------------------------------------
    def _on_read(self, index: int, subindex: int, od):
        reader = self._readers.get(index)
        return None if reader is None else reader(subindex)

    def _demand_qc(self) -> int:
        raw = round(self.plant.demand) - self.encoder_offset
        return -raw if self.sensor_polarity & 1 else raw

    def _history_entry(self, subindex: int) -> int:
        if subindex == 0:
            return len(self.history)
        return self.history[subindex - 1] if subindex <= len(self.history) else 0
