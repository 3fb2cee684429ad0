"""The EPOS 70/10 twin: a CANopen node that behaves like the car's steering drive.

It is a canopen `LocalNode` built from the same EDS as the driver uses, so SDO reads and
writes, PDO mapping, NMT and heartbeats go through canopen's own server code; on top of it
this module adds what the EPOS firmware does:

- the DS402 state machine driven by the controlword (docs/steering.md#ds402-states), fault
  reset only on a 0 -> 1 edge of bit 7, and only when no error persists;
- Position Mode (-1): 0x2062 is the position controller's demand, clipped by the software
  position limits 0x607D; the axis responds as `plant.PositionPlant` (fitted to the car);
- process data as mapped by the host: RPDOs applied on reception, TPDOs sent on SYNC
  (transmission type 1..240) or on change (254/255), only while NMT operational;
- faults with their EMCY: following error (0x8611) beyond 0x6065, software position limit
  (0xFF09), CAN life guard (0x8130) when the heartbeat consumed per 0x1016 stops, index
  processing (0xFF02) when enabled with an index the car's encoder does not have;
- the heartbeat producer 0x1017 (canopen's NmtSlave) and a boot-up message at power-up.

It also plays the person in the car: after power-up, once the host is talking to the drive
and the power stage is off, it turns the wheel lock to lock and back to the centre, as
the calibration procedure asks (docs/steering.md#power-up-sweep). The incremental encoder has no index, so the
position counter starts at 0 wherever the wheel stands at power-up, like the real one.
"""
from __future__ import annotations

import logging
import math
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import canopen
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import INTEGER_TYPES
from canopen.sdo import SdoAbortedError

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

log = logging.getLogger(__name__)
#: the longest step a person's hands take at once, however late the twin's thread runs
HAND_STEP_MAX_S = 0.01

INDEX_PROCESSING_ERROR = 0xFF02
SDO_ABORT_STATE = 0x08000022          # "data cannot be transferred: present device state"
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
_DISABLED = (ds402.NOT_READY, ds402.SWITCH_ON_DISABLED, ds402.READY, ds402.SWITCHED_ON, ds402.FAULT)


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


class EposTwin:
    """One simulated EPOS on a canopen Network (any python-can bus: virtual, slcan, ...)."""

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
        #: the person at the wheel: the wheel angle (rad) they steer to while the drive
        #: does not hold the wheel, or None (hands off). The sim's route follower.
        self.hands: Callable[[], float | None] | None = None
        #: the objects the firmware computes when read (index -> value at a subindex)
        self._readers: dict[int, Callable[[int], int | None]] = {
            0x6041: lambda sub: self.statusword,
            0x6064: lambda sub: self.position_qc,
            0x6062: lambda sub: self._demand_qc(),
            0x20F4: lambda sub: max(-32768, min(32767, round(self.plant.demand - self.plant.x))),
            0x6061: lambda sub: self.op_mode,
            0x2020: lambda sub: self.position_qc & 0xFFFF,
            0x1001: lambda sub: self._error_register(),
            0x1003: self._history_entry,
        }
        self._on_sync_tpdos: list = []          # the PDO maps as the last NMT start read them
        self._on_change_tpdos: list = []
        self._layouts: dict[int, _Layout | None] = {}

    # -- life -----------------------------------------------------------------------------
    def start(self) -> EposTwin:
        self.power_on()
        self._thread = clocks.Thread(target=self._run, name="epos-twin", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        self.power_off()

    def power_on(self) -> None:
        """Boot: fresh object dictionary, encoder counter at 0, boot-up message, pre-op."""
        with self._lock:
            self._boot_state()
            node = canopen.LocalNode(self.settings.node_id, canopen.import_od(self._eds, self.settings.node_id))
            node.add_read_callback(self._on_read)
            node.add_write_callback(self._on_write)
            self.network.add_node(node)
            self.network.subscribe(0, self._on_nmt)
            self.node = node
            for pdo in node.rpdo.map.values():
                pdo.add_callback(self._on_rpdo)
            self._compile_pdos()
            self._subscribe_sync(0x80)
            node.nmt.send_command(NMT_RESET_NODE)        # boot-up message
            node.nmt.send_command(NMT_PREOP)
            self.powered = True
            log.info("EPOS twin node %d powered on (wheel at %+.0f qc from centre)",
                     self.settings.node_id, self.plant.x)

    def power_off(self) -> None:
        """Silence: no heartbeat, no answers, as when the drive loses power."""
        with self._lock:
            if not self.powered:
                return
            self.powered = False
            node = self.node
            node.nmt.stop_heartbeat()
            for pdo in list(node.rpdo.map.values()) + list(node.tpdo.map.values()):
                self._unsubscribe(pdo.cob_id, pdo.on_message)
            self._unsubscribe(0, self._on_nmt)
            self._unsubscribe(self._sync_subscribed, self._on_sync)
            self._unsubscribe(self._hb_subscribed, self._on_host_heartbeat)
            self._hb_subscribed = self._sync_subscribed = None
            del self.network[node.id]

    def power_cycle(self) -> None:
        self.power_off()
        self.power_on()

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
        self._host_hb = (0, 0)                    # (producer node id, timeout ms) from 0x1016:1
        self._host_hb_last: float | None = None
        self._host_hb_seen_s: float | None = None
        self._tpdo_last: dict[int, bytes] = {}
        self._sync_count = 0
        self._last_step = now
        self._swept = False
        self._sweep: list[tuple[float, float, float, float]] | None = None   # t0, t1, a, b

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
        return self._sweep is not None

    def inject_error(self, code: int) -> None:
        """A device error as the hardware would raise it (over temperature, ...)."""
        with self._lock:
            self._fault(code, self._clock())

    # -- time -----------------------------------------------------------------------------
    def _run(self) -> None:
        period = self.settings.step_period_s
        while not self._stop.wait(period):
            try:
                self.step()
            except Exception:                       # the twin must keep running for the sim
                log.exception("EPOS twin step failed")

    def step(self, now: float | None = None) -> None:
        with self._lock:
            if not self.powered:
                return
            now = self._clock() if now is None else now
            dt = max(0.0, now - self._last_step)
            self._last_step = now
            self._move(dt, now)
            self._supervise(now)
            self._tpdos_on_change()

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
            self._person(now, dt)
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
        if self._host_hb_lost(now) and self._host_hb_seen_s is not None:
            log.warning("EPOS twin: host heartbeat lost")
            self._host_hb_seen_s = None
            if LIFE_GUARD_ERROR not in self.errors:
                self._fault(LIFE_GUARD_ERROR, now)

    def _host_hb_lost(self, now: float) -> bool:
        producer, timeout_ms = self._host_hb
        if not timeout_ms or self._host_hb_last is None:
            return False                             # monitoring starts with the first one
        return now - self._host_hb_last > timeout_ms / 1000.0

    # -- the person turning the wheel ------------------------------------------------------
    def ask_for_sweep(self) -> bool:
        """The person at the wheel is asked to turn it lock to lock again (the steering
        service restarted its calibration and says so); False if a sweep is under way."""
        if self._sweep is not None:
            return False
        self._swept = False
        return True

    def _person(self, now: float, dt: float) -> None:
        s = self.settings
        if self._sweep is None and s.sweep and not self._swept and self._host_hb_seen_s is not None \
                and self.node.nmt.state == "OPERATIONAL" and now - self._host_hb_seen_s >= s.sweep_delay_s:
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

    def _let_go(self) -> None:
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

    # -- faults ---------------------------------------------------------------------------
    def _fault(self, code: int, now: float) -> None:
        if code not in self.errors:
            self.errors.append(code)
            self.history.insert(0, code)
            del self.history[5:]
        log.info("EPOS twin fault: 0x%04X %s in %s", code, emcy_name(code), self.state)
        self.emcy_sent.append(code)
        if self.node.nmt.state != "STOPPED":
            self.node.emcy.send(code, self._error_register())
        p = self.plant
        if self.state in (ds402.OPERATION_ENABLED, ds402.QUICK_STOP_ACTIVE):
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
            if code == LIFE_GUARD_ERROR and self._host_hb_lost(now):
                persisting.append(code)
            elif code == SOFTWARE_POSITION_LIMIT_ERROR and not self.limits[0] <= self.position_qc <= self.limits[1]:
                persisting.append(code)
        self.errors = persisting
        if persisting:
            log.info("EPOS twin: fault reset refused, %s persists", emcy_name(persisting[0]))
            return
        self.state = ds402.SWITCH_ON_DISABLED
        self.node.emcy.reset(0)
        log.info("EPOS twin: fault reset")

    # -- DS402 ----------------------------------------------------------------------------
    def _on_controlword(self, cw: int) -> None:
        previous, self.controlword = self.controlword, cw
        now = self._clock()
        # (an RPDO has just stepped the twin: stepping again at the same instant changes
        # nothing but asks the person's hands once more, and the sim's route follower's
        # path depends on how often it is asked: kept, for the same sim)
        self.step(now)
        st = self.state
        if st == ds402.FAULT:
            if cw & 0x80 and not previous & 0x80:
                self._try_fault_reset(now)
            return
        if st == ds402.FAULT_REACTION or cw & 0x80:
            return
        new = st
        if cw & 0x02 == 0:                                       # disable voltage
            if st in (ds402.READY, ds402.SWITCHED_ON, ds402.OPERATION_ENABLED, ds402.QUICK_STOP_ACTIVE):
                new = ds402.SWITCH_ON_DISABLED
        elif cw & 0x06 == 0x02:                                  # quick stop
            if st in (ds402.READY, ds402.SWITCHED_ON):
                new = ds402.SWITCH_ON_DISABLED
            elif st == ds402.OPERATION_ENABLED:
                new = ds402.QUICK_STOP_ACTIVE
        elif cw & 0x07 == 0x06:                                  # shutdown
            if st in (ds402.SWITCH_ON_DISABLED, ds402.SWITCHED_ON, ds402.OPERATION_ENABLED):
                new = ds402.READY
        elif cw & 0x0F == 0x07:                                  # switch on / disable operation
            if st in (ds402.READY, ds402.OPERATION_ENABLED):
                new = ds402.SWITCHED_ON
        elif cw & 0x0F == 0x0F:                                  # (switch on +) enable operation
            if st in (ds402.READY, ds402.SWITCHED_ON, ds402.QUICK_STOP_ACTIVE):
                new = ds402.OPERATION_ENABLED
        if new != st:
            self._enter(new, now)

    def _enter(self, new: str, now: float) -> None:
        p = self.plant
        if new == ds402.OPERATION_ENABLED and self.state != ds402.QUICK_STOP_ACTIVE:
            p.reset(p.x)
            self._let_go()
        elif new == ds402.QUICK_STOP_ACTIVE:
            dec = self.settings.quickstop_decel_qc_s2
            self._stop_target = p.x + p.v * abs(p.v) / (2.0 * dec)
        elif new in _DISABLED:
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

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        self._write(index, subindex, od.decode_raw(data))

    def _write(self, index: int, subindex: int, value) -> None:
        """An object written, by SDO or RPDO."""
        enabled = self.state not in _DISABLED
        if index == 0x6040:
            self._on_controlword(value)
        elif index == 0x2062:
            self.setting_qc = value
        elif index == 0x6060:
            self.op_mode = value
        elif index == 0x6065:
            self.max_following_error = value
        elif index == 0x607D:
            lo, hi = self.limits
            self.limits = (value, hi) if subindex == 1 else (lo, value)
        elif index == 0x2210:
            if enabled:
                raise SdoAbortedError(SDO_ABORT_STATE)
            if subindex == 2:
                self.sensor_type = value
            elif subindex == 4:
                self.sensor_polarity = value
        elif 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
            if self.node.nmt.state == "OPERATIONAL":
                raise SdoAbortedError(SDO_ABORT_STATE)
        elif index == 0x1016 and subindex == 1:
            self._host_hb = ((value >> 16) & 0x7F, value & 0xFFFF)
            self._host_hb_last = self._host_hb_seen_s = None     # a host (re)starting: it
            self._swept = False                                  # will ask for a new sweep,
            self._sweep = None                                   # from the start
            producer = self._host_hb[0]
            self._unsubscribe(self._hb_subscribed, self._on_host_heartbeat)
            self._hb_subscribed = None
            if producer and self._host_hb[1]:
                self.network.subscribe(0x700 + producer, self._on_host_heartbeat)
                self._hb_subscribed = 0x700 + producer
        elif index == 0x1005:
            self._subscribe_sync(value & 0x7FF)

    def _subscribe_sync(self, cob_id: int) -> None:
        self._unsubscribe(self._sync_subscribed, self._on_sync)
        self.network.subscribe(cob_id, self._on_sync)
        self._sync_subscribed = cob_id

    def _unsubscribe(self, cob_id: int | None, callback) -> None:
        if cob_id is not None and callback in self.network.subscribers.get(cob_id, []):
            self.network.unsubscribe(cob_id, callback)

    # -- network events (canopen's receive thread) ----------------------------------------
    def _on_nmt(self, can_id, data, timestamp) -> None:
        if len(data) < 2 or data[1] not in (0, self.settings.node_id):
            return
        command = data[0]
        if command == NMT_RESET_NODE:       # a reboot takes the lock: started from outside it
            clocks.Thread(target=self.power_cycle, daemon=True).start()
            return
        with self._lock:
            if command == NMT_START:
                self._load_pdos()
            elif command in (NMT_STOP, NMT_PREOP, NMT_RESET_COMM):
                self._tpdo_last.clear()

    def _on_host_heartbeat(self, can_id, data, timestamp) -> None:
        with self._lock:
            now = self._clock()
            self._host_hb_last = now
            if self._host_hb_seen_s is None:
                self._host_hb_seen_s = now

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self._lock:
            if not self.powered or self.node.nmt.state != "OPERATIONAL":
                return
            self.step()
            self._sync_count += 1
            for pdo in self._on_sync_tpdos:
                if self._sync_count % pdo.trans_type == 0:
                    self._send_tpdo(pdo)

    def _on_rpdo(self, pdo) -> None:
        with self._lock:
            if not self.powered or self.node.nmt.state != "OPERATIONAL":
                return
            self.step()         # the axis up to now on the old setpoint: the new one acts from its arrival
            if len(pdo.data) * 8 < pdo.length:
                self._fault(0x8210, self._clock())        # CAN PDO length error
                return
            layout = self._layouts.get(id(pdo))
            if layout is None:
                for var in pdo:
                    if var.length:
                        self.node.set_data(var.index, var.subindex, var.get_data())
                return
            # what node.set_data does for each variable, without canopen's per-variable
            # unpacking and lookups: our write callback, then the object's bytes stored
            store = self.node.data_store
            for var, value, data in layout.unpack(pdo.data):
                self._write(var.index, var.subindex, value)
                store.setdefault(var.index, {})[var.subindex] = data

    def _load_pdos(self) -> None:
        """On NMT start: take the mapping the host wrote (our own OD, through our SDO server)."""
        node = self.node
        for pdo in list(node.rpdo.map.values()) + list(node.tpdo.map.values()):
            if pdo.cob_id is not None:
                self._unsubscribe(pdo.cob_id, pdo.on_message)
        node.rpdo.read()
        node.tpdo.read()
        for pdo in node.tpdo.map.values():         # our TPDOs are ours to send, not to hear
            if pdo.enabled:
                self._unsubscribe(pdo.cob_id, pdo.on_message)
        self._tpdo_last.clear()
        self._compile_pdos()

    def _compile_pdos(self) -> None:
        """What each SYNC and step needs of the mapping, worked out once: the mapping
        changes only here (read at NMT start), while the PDOs go 100 times a second."""
        node = self.node
        tpdos = list(node.tpdo.map.items())
        self._on_sync_tpdos = [pdo for _, pdo in tpdos if pdo.enabled and pdo.trans_type
                               and 1 <= pdo.trans_type <= 240]
        self._on_change_tpdos = [(n, pdo) for n, pdo in tpdos if pdo.enabled and pdo.trans_type in (254, 255)]
        self._layouts = {id(pdo): _Layout.of(pdo, self._readers)
                         for pdo in list(node.rpdo.map.values()) + [pdo for _, pdo in tpdos]}

    def _tpdo_data(self, pdo) -> bytes | None:
        """The mapped objects' bytes as node.get_data gives them, packed at once (None:
        a mapping `_Layout` does not cover)."""
        layout = self._layouts.get(id(pdo))
        return None if layout is None else layout.pack()

    def _send_tpdo(self, pdo) -> bytes:
        data = self._tpdo_data(pdo)
        if data is not None:
            pdo.data[:len(data)] = data
        else:
            mapped = [var for var in pdo if var.length]
            if any(var.offset % 8 or var.length % 8 for var in mapped):   # bit fields: canopen packs them
                for var in mapped:
                    var.set_data(self.node.get_data(var.index, var.subindex))
            else:           # whole bytes: one join, not canopen's per-variable packing
                data = b"".join([self.node.get_data(var.index, var.subindex) for var in mapped])
                pdo.data[:len(data)] = data
        self.network.send_message(pdo.cob_id, pdo.data)
        return bytes(pdo.data)

    def _tpdos_on_change(self) -> None:
        if not self._on_change_tpdos or self.node.nmt.state != "OPERATIONAL":
            return
        for n, pdo in self._on_change_tpdos:
            data = self._tpdo_data(pdo)
            if data is None:
                data = b"".join(self.node.get_data(v.index, v.subindex) for v in pdo if v.length)
            if self._tpdo_last.get(n) != data:
                self._tpdo_last[n] = self._send_tpdo(pdo)


class _Layout:
    """A PDO of whole integers at whole bytes, each as long as its object (what the EPOS
    maps): one struct packs or unpacks it all, instead of canopen's per-variable bit
    slicing and object dictionary lookups. Other mappings go through canopen."""

    def __init__(self, variables: list, fmt: struct.Struct, readers: list):
        self.variables, self.struct, self.readers = variables, fmt, readers

    @classmethod
    def of(cls, pdo, readers: dict[int, Callable[[int], int | None]]) -> _Layout | None:
        variables, fmt, bits, served = [], "<", 0, []
        for var in pdo:
            if not var.length:
                continue
            od = var.od
            code = ODVariable.STRUCT_TYPES.get(od.data_type)
            if type(code) is not struct.Struct or od.data_type not in INTEGER_TYPES or var.offset != bits \
                    or var.length != len(od) or od.min is not None or od.max is not None:
                return None
            variables.append(var)
            fmt += code.format.lstrip("<")
            bits += var.length
            reader = readers.get(var.index)
            served.append(None if reader is None else (reader, var.subindex))
        if not variables:
            return None
        return cls(variables, struct.Struct(fmt), served if None not in served else [])

    def unpack(self, data: bytes) -> list[tuple[Any, int, bytes]]:
        """(variable, value, its bytes) for each mapped variable of a received PDO."""
        values = self.struct.unpack_from(data)
        return [(var, value, bytes(data[var.offset // 8:(var.offset + var.length) // 8]))
                for var, value in zip(self.variables, values)]

    def pack(self) -> bytes | None:
        """The bytes of a PDO whose objects the twin computes (its read callback), or None
        (objects from the data store, or a value that does not fit: canopen says why)."""
        if not self.readers:
            return None
        try:
            return self.struct.pack(*[read(sub) for read, sub in self.readers])
        except struct.error:
            return None

