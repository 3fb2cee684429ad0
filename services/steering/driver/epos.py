"""The Maxon EPOS 70/10 on CANopen: configuration by SDO, setpoints by RPDO, feedback by
TPDO on SYNC, heartbeats both ways, emergencies by name.

    >>> drive = EposDrive(DriveSettings(interface="slcan", channel="socket://127.0.0.1:5005",
    ...                                 bus_options={"sleep_after_open": 0}))
    >>> drive.open(); drive.configure(limits_qc=None)
    >>> drive.cycle()                      # call every sync_period_s: heartbeat, RPDO, SYNC
    >>> drive.feedback().position_qc

The drive runs in EPOS Position Mode (operation mode -1): the setpoint object 0x2062 is the
position controller's demand directly, clipped by the software position limits 0x607D.
Process data (all mapped at start, firmware specification §14.16-14.31; docs/steering.md#pdo-mapping):

    RPDO1  0x200+id  asynchronous  controlword 0x6040 (u16), position setting 0x2062 (i32)
    TPDO1  0x180+id  on SYNC       statusword 0x6041 (u16), position actual 0x6064 (i32)
    TPDO2  0x280+id  on SYNC       following error 0x20F4 (i16), position demand 0x6062 (i32),
                                   operation mode display 0x6061 (i8)

The host sends its own heartbeat (0x700 + host node id) from the same loop that sends the
setpoints, and configures the drive to consume it (0x1016): if the host process dies or its
loop hangs, the drive faults by itself (CAN Life Guard Error) and stops the motor.

This module imports neither zenoh nor msgpack; the state machine policy (when to enable,
when to reset a fault: `arming.py`) belongs to the caller.
"""
from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import can
import canopen
from canopen.profiles.p402 import BaseNode402

from viena.common import clock as clocks
from viena.common import urlhandler
from viena.services.steering.driver.emcy import Emcy
from viena.services.steering.driver.slcan import SlcanBus
from viena.services.steering.model import ds402
from viena.services.steering.model.drive import EDS_PATH as EDS_PATH
from viena.services.steering.model.drive import NMT_BOOTUP as NMT_BOOTUP
from viena.services.steering.model.drive import NMT_OPERATIONAL as NMT_OPERATIONAL
from viena.services.steering.model.drive import POSITION_MODE as POSITION_MODE
from viena.services.steering.model.drive import DriveSettings as DriveSettings
from viena.services.steering.model.drive import Feedback as Feedback

log = logging.getLogger(__name__)

LIMIT_DISABLED = (-(2 ** 31), 2 ** 31 - 1)          # 0x607D values that switch the check off
HEARTBEAT = bytes([NMT_OPERATIONAL])
#: the process data as `_map_process_data` lays it out (CiA 301: little endian), packed and
#: read here: canopen's `Variable.raw` formats a debug message on every read
RPDO1 = struct.Struct("<Hi")      # controlword 0x6040 (u16), position setting 0x2062 (i32)
TPDO1 = struct.Struct("<Hi")      # statusword 0x6041 (u16), position actual 0x6064 (i32)
TPDO2 = struct.Struct("<hib")     # following error 0x20F4 (i16), demand 0x6062 (i32), mode 0x6061 (i8)


class DriveError(Exception):
    """The drive did not do what was asked (an SDO abort, a timeout, a wrong read-back)."""


class EposDrive:
    """One EPOS on one CAN bus. Thread-safe: any thread may command, one loop cycles."""

    def __init__(self, settings: DriveSettings | None = None, bus=None,
                 clock: Callable[[], float] = clocks.monotonic):
        self.settings = settings or DriveSettings()
        self._clock = clock
        self._bus = bus
        self.network: canopen.Network | None = None
        self.node: BaseNode402 | None = None
        self._tx_lock = threading.RLock()
        self._fb_lock = threading.Condition()  # noqa: TID251 - wait_feedback's, for tests
        self._feedback = Feedback()
        self._controlword = ds402.CW_DISABLE_VOLTAGE
        self._target_qc = 0
        self._next_heartbeat = 0.0
        self._heartbeat_s: float | None = None
        self._heartbeat_state: int | None = None
        self._emcy_listeners: list[Callable[[Emcy], None]] = []
        self._bootup_listeners: list[Callable[[], None]] = []
        self.emcy_log: list[Emcy] = []
        self.tx_frames = 0

    # -- connection ---------------------------------------------------------------------
    @property
    def _net(self) -> canopen.Network:
        """The open network: using the drive before open() (or after close()) is a bug."""
        if self.network is None:
            raise RuntimeError("EPOS drive not open")
        return self.network

    @property
    def _node(self) -> BaseNode402:
        if self.node is None:
            raise RuntimeError("EPOS drive not open")
        return self.node

    def open(self) -> None:
        s = self.settings
        with self._fb_lock:
            self._feedback = Feedback()
        self._heartbeat_s = self._heartbeat_state = None
        net = self.network = canopen.Network(self._bus)
        net.NOTIFIER_CYCLE = 0.1      # how long closing waits for the receive thread
        options = _bus_options(s)
        if self._bus is None and s.interface == "slcan":            # ours (driver/slcan.py); connect keeps it
            net.bus = SlcanBus(s.channel, bitrate=s.bitrate, **options)
        net.connect(interface=s.interface, channel=s.channel, bitrate=s.bitrate, **options)
        _notifier(net).add_listener(_ReceiveFailure(net))
        od = canopen.import_od(s.eds, s.node_id)
        node = self.node = BaseNode402(s.node_id, od)
        net.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = s.sdo_timeout_s
        node.nmt.add_heartbeat_callback(self._on_heartbeat)
        node.emcy.add_callback(self._on_emcy)
        self._map_process_data()
        log.info("EPOS node %d on %s %s", s.node_id, s.interface, s.channel)

    def close(self) -> None:
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception as exc:      # a vanished adapter must not stop the shutdown
                log.debug("disconnect: %s", exc)
            self.network = None

    def add_emcy_listener(self, fn: Callable[[Emcy], None]) -> None:
        self._emcy_listeners.append(fn)

    def add_bootup_listener(self, fn: Callable[[], None]) -> None:
        """Called when the drive announces a (re)boot: its configuration and position are gone."""
        self._bootup_listeners.append(fn)

    # -- configuration (SDO) --------------------------------------------------------------
    def configure(self, limits_qc: tuple[int, int] | None = None) -> None:
        """Write the start-up configuration, map the PDOs and start the node.

        Leaves the drive with its power stage off (switch on disabled), in Position Mode.
        """
        s, node = self.settings, self._node
        node.nmt.state = "PRE-OPERATIONAL"
        with self._tx_lock:
            self._controlword = ds402.CW_DISABLE_VOLTAGE
        self.write(0x6040, 0, ds402.CW_DISABLE_VOLTAGE, verify=False)
        self.write(0x2210, 1, s.encoder_pulses)
        self.write(0x2210, 2, s.sensor_type)
        self.write(0x2210, 4, s.sensor_polarity)
        self.write(0x6065, 0, s.max_following_error_qc)
        self.set_position_limits(limits_qc)
        self.write(0x6060, 0, POSITION_MODE)
        self.write(0x1005, 0, 0x80)
        self.write(0x1017, 0, round(s.drive_heartbeat_period_s * 1000))
        self.write(0x1016, 1, (s.host_node_id << 16) | round(s.host_heartbeat_timeout_s * 1000))
        self._save_process_data()
        node.nmt.state = "OPERATIONAL"
        log.info("EPOS configured: %d pulses, sensor type %d, max following error %d qc, "
                 "heartbeat %d ms, consumes host %d within %d ms", s.encoder_pulses,
                 s.sensor_type, s.max_following_error_qc,
                 round(s.drive_heartbeat_period_s * 1000), s.host_node_id,
                 round(s.host_heartbeat_timeout_s * 1000))

    def set_position_limits(self, limits_qc: tuple[int, int] | None) -> None:
        """Software position limits 0x607D (min, max) in qc; None switches them off."""
        lo, hi = LIMIT_DISABLED if limits_qc is None else (int(limits_qc[0]), int(limits_qc[1]))
        if lo >= hi:
            raise DriveError(f"software position limits {lo}..{hi} are empty")
        self.write(0x607D, 1, lo)
        self.write(0x607D, 2, hi)
        if limits_qc is not None:
            log.info("EPOS software position limits %d .. %d qc", lo, hi)

    def write(self, index: int, subindex: int, value: int, verify: bool = True) -> None:
        """SDO download, read back to be sure the drive kept it."""
        var = self._node.sdo[index] if subindex == 0 and not _has_subs(self._node, index) \
            else self._node.sdo[index][subindex]
        try:
            var.raw = value
            if verify and var.raw != value:
                raise DriveError(f"0x{index:04X}:{subindex} reads back {var.raw}, wrote {value}")
        except canopen.SdoAbortedError as exc:
            raise DriveError(f"0x{index:04X}:{subindex} = {value}: {exc}") from None
        except canopen.SdoCommunicationError as exc:
            raise DriveError(f"0x{index:04X}:{subindex}: no answer ({exc})") from None

    def read(self, index: int, subindex: int = 0) -> int:
        var = self._node.sdo[index] if subindex == 0 and not _has_subs(self._node, index) \
            else self._node.sdo[index][subindex]
        try:
            return var.raw
        except (canopen.SdoAbortedError, canopen.SdoCommunicationError) as exc:
            raise DriveError(f"0x{index:04X}:{subindex}: {exc}") from None

    def error_history(self, depth: int = 5) -> list[int]:
        """The drive's own record of its last errors (0x1003, newest first), as EMCY codes:
        why it is in fault when the EMCY went by while nobody listened (a service restart)."""
        count = min(self.read(0x1003, 0), depth)
        return [self.read(0x1003, k) & 0xFFFF for k in range(1, count + 1)]

    def _map_process_data(self) -> None:
        """The PDO layout this driver uses, built locally (saved to the drive by configure)."""
        node, nid = self._node, self.settings.node_id
        layout = (
            (node.rpdo, 1, 0x200, 255, (0x6040, 0x2062)),
            (node.tpdo, 1, 0x180, 1, (0x6041, 0x6064)),
            (node.tpdo, 2, 0x280, 1, (0x20F4, 0x6062, 0x6061)),
        )
        for pdos in (node.rpdo, node.tpdo):
            for n in range(1, 5):
                pdo = pdos[n]
                pdo.clear()
                pdo.enabled = False
                pdo.cob_id = (0x100 * n + (0x100 if pdos is node.rpdo else 0x80)) + nid
        for pdos, n, base, trans_type, objects in layout:
            pdo = pdos[n]
            pdo.cob_id = base + nid
            pdo.trans_type = trans_type
            pdo.rtr_allowed = False
            for index in objects:
                pdo.add_variable(index)
            pdo.enabled = True
        self._rpdo = node.rpdo[1]
        self._tpdo1, self._tpdo2 = node.tpdo[1].cob_id, node.tpdo[2].cob_id

    def _save_process_data(self) -> None:
        node = self._node
        try:
            for pdos in (node.rpdo, node.tpdo):
                for n in range(1, 5):
                    pdos[n].save()
        except canopen.SdoAbortedError as exc:
            raise DriveError(f"PDO mapping refused: {exc}") from None
        except canopen.SdoCommunicationError as exc:
            raise DriveError(f"PDO mapping: no answer ({exc})") from None
        # canopen subscribes each saved PDO's map; none is wanted. Our RPDO's contents are
        # ours alone: a frame from another host on the bus with the same COB-ID must never
        # overwrite them. The TPDOs (Feedback keeps what they say, 200 a second) come
        # straight from the network, not through the maps' bookkeeping nobody here reads.
        for pdos in (node.rpdo, node.tpdo):
            for n in range(1, 5):
                if pdos[n].on_message in self._net.subscribers.get(pdos[n].cob_id, []):
                    self._net.unsubscribe(pdos[n].cob_id, pdos[n].on_message)
        for cob_id in (self._tpdo1, self._tpdo2):
            self._net.subscribe(cob_id, self._on_tpdo)

    # -- process data ---------------------------------------------------------------------
    def cycle(self, target_qc: int | None = None) -> None:
        """One control period: host heartbeat when due, the setpoint RPDO (with a new
        target if given), then SYNC."""
        now = self._clock()
        with self._tx_lock:
            if target_qc is not None:
                self._target_qc = int(target_qc)
            frames = [(self._rpdo.cob_id, RPDO1.pack(self._controlword, self._target_qc)), (self._net.sync.cob_id, b"")]
            heartbeat_due = now >= self._next_heartbeat
            if heartbeat_due:
                frames.insert(0, (0x700 + self.settings.host_node_id, HEARTBEAT))
            self._send_all(frames)
            if heartbeat_due:                   # not before it went: a failed write retries it next period
                self._next_heartbeat = now + self.settings.host_heartbeat_period_s

    def command(self, controlword: int) -> None:
        """Send a controlword now (the RPDO carries the current target with it)."""
        with self._tx_lock:
            self._controlword = controlword & 0xFFFF
            self._send_rpdo()

    def send_target(self, target_qc: int, controlword: int | None = None) -> None:
        """Send a position setpoint now (and optionally a new controlword in the same frame)."""
        with self._tx_lock:
            self._target_qc = int(target_qc)
            if controlword is not None:
                self._controlword = controlword & 0xFFFF
            self._send_rpdo()

    def _send_rpdo(self) -> None:
        self._send_all([(self._rpdo.cob_id, RPDO1.pack(self._controlword, self._target_qc))])

    def _send_all(self, frames: list[tuple[int, bytes]]) -> None:
        """These frames in order: with one write where the bus can (driver/slcan.py)."""
        net = self._net
        bus = net.bus
        if isinstance(bus, SlcanBus):
            with net.send_lock:
                bus.send_frames(frames)
            net.check()            # as send_message does: a failed receive thread shows here
        else:
            for cob_id, data in frames:
                net.send_message(cob_id, data)
        self.tx_frames += len(frames)

    @property
    def controlword(self) -> int:
        return self._controlword

    @property
    def target_qc(self) -> int:
        return self._target_qc

    def feedback(self) -> Feedback:
        with self._fb_lock:
            return self._feedback

    def wait_feedback(self, predicate: Callable[[Feedback], bool], timeout_s: float) -> bool:
        """Block until a TPDO makes predicate(feedback) true, or timeout (for tests). A
        threading.Condition waits on the wall clock, so the deadline is the wall clock's:
        not for threads of the lockstep runner."""
        end = time.monotonic() + timeout_s  # noqa: TID251 - the Condition's clock
        with self._fb_lock:
            while not predicate(self._feedback):
                left = end - time.monotonic()  # noqa: TID251 - the Condition's clock
                if left <= 0:
                    return False
                self._fb_lock.wait(left)
            return True

    def heartbeat_age(self, now: float | None = None) -> float:
        """Seconds since the drive's last heartbeat (inf if none yet)."""
        if self._heartbeat_s is None:
            return float("inf")
        return (self._clock() if now is None else now) - self._heartbeat_s

    @property
    def heartbeat_state(self) -> int | None:
        return self._heartbeat_state

    # -- callbacks from canopen's receive thread ------------------------------------------
    def _on_tpdo(self, cob_id: int, data: bytearray, _timestamp: float) -> None:
        now = self._clock()
        if len(data) < (TPDO1 if cob_id == self._tpdo1 else TPDO2).size:
            return          # not what the drive was told to send (another node on its COB-ID): not feedback
        with self._fb_lock:
            fb = self._feedback
            if cob_id == self._tpdo1:
                statusword, position_qc = TPDO1.unpack_from(data)
                fb = Feedback(statusword, position_qc, fb.following_error_qc, fb.demand_qc, fb.op_mode,
                              now, fb.count + 1)
            else:
                following_error_qc, demand_qc, op_mode = TPDO2.unpack_from(data)
                fb = Feedback(fb.statusword, fb.position_qc, following_error_qc, demand_qc, op_mode,
                              now, fb.count + 1)
            self._feedback = fb
            self._fb_lock.notify_all()

    def _on_heartbeat(self, state: int) -> None:
        self._heartbeat_s = self._clock()
        previous, self._heartbeat_state = self._heartbeat_state, state
        if state == NMT_BOOTUP and previous is not None:
            log.warning("EPOS node %d rebooted", self.settings.node_id)
            for fn in self._bootup_listeners:
                fn()

    def _on_emcy(self, error) -> None:
        emcy = Emcy(error.code, error.register, bytes(error.data))
        self.emcy_log.append(emcy)
        del self.emcy_log[:-50]
        for fn in self._emcy_listeners:
            fn(emcy)


class _ReceiveFailure(can.Listener):
    """When the adapter goes away, stop the receive thread quietly instead of letting it
    die with a traceback; canopen raises the stored error on the next send, which is
    where the owner of the drive notices and reconnects."""

    def __init__(self, network: canopen.Network):
        self._network = network

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        log.warning("CAN receive stopped: %s", exc)
        _notifier(self._network).stop(timeout=0)


def _bus_options(s: DriveSettings) -> dict[str, Any]:
    """python-can's arguments, with what slcan needs: the port's read timeout is how often
    the receive thread wakes when nothing comes (python-can's 0.001 s is 1000 times a
    second, on the car's adapter too); and on a TCP socket (the simulated drive) no adapter
    to wait for."""
    options = dict(s.bus_options)
    if s.interface == "slcan":
        options.setdefault("timeout", 0.01)           # idle polling: 100/s, not 1000/s
    if s.interface == "slcan" and s.channel.startswith("socket://"):
        options.setdefault("sleep_after_open", 0)     # no adapter to reset on a socket
        urlhandler.use()                              # whole reads, not a byte at a time
    return options


def _notifier(network: canopen.Network) -> can.Notifier:
    """The receive thread of a connected network (connect() starts it)."""
    if network.notifier is None:
        raise RuntimeError("CAN network not connected")
    return network.notifier


def _has_subs(node, index: int) -> bool:
    return not isinstance(node.object_dictionary[index], canopen.objectdictionary.ODVariable)
