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

The parts, one module each: the DS402 state machine is a table (model/ds402.py: TRANSITIONS,
EPOS_STATUSWORD) that `epos_firmware.EposFirmware` reads, with the motion, the faults and
the values the firmware computes; the person's hands are `twin_hands.WheelHands`; the host
heartbeat it consumes `twin_heartbeat.HostHeartbeat`; the PDO mapping and the TPDOs
`twin_pdos.TwinPdos` (`pdo_layout.PdoLayout`). This module is the node's life on the network,
its object dictionary's writes and the network's events.
"""
from __future__ import annotations

import logging

import canopen
from canopen.sdo import SdoAbortedError

from viena.common import clock as clocks
from viena.services.steering.model import ds402
from viena.services.steering.simulator.epos_firmware import EposFirmware, TwinSettings
from viena.services.steering.simulator.twin_pdos import maps_of, unsubscribe

log = logging.getLogger(__name__)

SDO_ABORT_STATE = 0x08000022          # "data cannot be transferred: present device state"
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82

__all__ = ["EposTwin", "TwinSettings"]


class EposTwin(EposFirmware):
    """One simulated EPOS on a canopen Network (any python-can bus: virtual, slcan, ...)."""

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
            for _, pdo in maps_of(node.rpdo):
                pdo.add_callback(self._on_rpdo)
            self.pdos.compile(node)
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
            node, net = self._live, self.network
            node.nmt.stop_heartbeat()
            for _, pdo in maps_of(node.rpdo) + maps_of(node.tpdo):
                unsubscribe(net, pdo.cob_id, pdo.on_message)
            unsubscribe(net, 0, self._on_nmt)
            unsubscribe(net, self._sync_subscribed, self._on_sync)
            unsubscribe(net, self._hb_subscribed, self._on_host_heartbeat)
            self._hb_subscribed = self._sync_subscribed = None
            del self.network[self.settings.node_id]         # (the node's id)

    def power_cycle(self) -> None:
        self.power_off()
        self.power_on()

    def _run(self) -> None:
        period = self.settings.step_period_s
        while not self._stop.wait(period):
            try:
                self.step()
            except Exception:                       # the twin must keep running for the sim
                log.exception("EPOS twin step failed")
    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        self._write(index, subindex, od.decode_raw(data))

    def _write(self, index: int, subindex: int, value) -> None:
        """An object written, by SDO or RPDO."""
        enabled = self.state not in ds402.POWER_STAGE_OFF
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
            if self._live.nmt.state == "OPERATIONAL":
                raise SdoAbortedError(SDO_ABORT_STATE)
        elif index == 0x1016 and subindex == 1:
            cob_id = self.host_hb.configure(value)              # a host (re)starting: it
            self.person.reset()                                  # will ask for a new sweep
            unsubscribe(self.network, self._hb_subscribed, self._on_host_heartbeat)
            self._hb_subscribed = None
            if cob_id is not None:
                self.network.subscribe(cob_id, self._on_host_heartbeat)
                self._hb_subscribed = cob_id
        elif index == 0x1005:
            self._subscribe_sync(value & 0x7FF)

    def _subscribe_sync(self, cob_id: int) -> None:
        unsubscribe(self.network, self._sync_subscribed, self._on_sync)
        self.network.subscribe(cob_id, self._on_sync)
        self._sync_subscribed = cob_id
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
                self.pdos.load(self._live)
            elif command in (NMT_STOP, NMT_PREOP, NMT_RESET_COMM):
                self.pdos.tpdo_last.clear()

    def _on_host_heartbeat(self, can_id, data, timestamp) -> None:
        with self._lock:
            self.host_hb.heard(self._clock())

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self._lock:
            if not self.powered or self._live.nmt.state != "OPERATIONAL":
                return
            self.step()
            self.pdos.on_sync(self._live)

    def _on_rpdo(self, pdo) -> None:
        with self._lock:
            node = self._live
            if not self.powered or node.nmt.state != "OPERATIONAL":
                return
            self.step()         # the axis up to now on the old setpoint: the new one acts from its arrival
            if len(pdo.data) * 8 < pdo.length:
                self._fault(0x8210, self._clock())        # CAN PDO length error
                return
            layout = self.pdos.layout(pdo)
            if layout is None:
                for var in pdo:
                    if var.length:
                        node.set_data(var.index, var.subindex, var.get_data())
                return
            # what node.set_data does for each variable, without canopen's per-variable
            # unpacking and lookups: our write callback, then the object's bytes stored
            store = node.data_store
            for var, value, data in layout.unpack(pdo.data):
                self._write(var.index, var.subindex, value)
                store.setdefault(var.index, {})[var.subindex] = data
