"""The EPOS twin's process data: the mapping the host wrote, read at NMT start, and the
TPDOs it sends on SYNC (transmission type 1..240) or on change (254/255). The RPDOs'
values reach the twin through its object dictionary writes (epos_twin.EposTwin._on_rpdo)."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import canopen

from viena.services.steering.simulator.pdo_layout import PdoLayout

#: the objects the firmware computes when read (index -> value at a subindex)
Readers = dict[int, Callable[[int], int | None]]


def unsubscribe(network: canopen.Network, cob_id: int | None, callback: Callable[..., Any]) -> None:
    """Stop hearing `cob_id` (if subscribed with `callback`)."""
    if cob_id is not None and callback in network.subscribers.get(cob_id, []):
        network.unsubscribe(cob_id, callback)


def maps_of(pdos: Any) -> list[tuple[int, Any]]:
    """A node's RPDO or TPDO maps by number (canopen types `map` as optional; a node's has one)."""
    return list((pdos.map or {}).items())


class TwinPdos:
    """The PDOs of one twin node, and what it last sent."""

    def __init__(self, network: canopen.Network, readers: Readers):
        self.network, self.readers = network, readers
        self._on_sync_tpdos: list[Any] = []          # the PDO maps as the last NMT start read them
        self._on_change_tpdos: list[tuple[int, Any]] = []
        self._layouts: dict[int, PdoLayout | None] = {}
        self.reset()

    def reset(self) -> None:
        """Power-up: nothing sent yet, no SYNC counted."""
        self.tpdo_last: dict[int, bytes] = {}
        self._sync_count = 0

    def layout(self, pdo: Any) -> PdoLayout | None:
        return self._layouts.get(id(pdo))

    def load(self, node: canopen.LocalNode) -> None:
        """On NMT start: take the mapping the host wrote (our own OD, through our SDO server)."""
        for pdo in [pdo for _, pdo in maps_of(node.rpdo) + maps_of(node.tpdo)]:
            if pdo.cob_id is not None:
                unsubscribe(self.network, pdo.cob_id, pdo.on_message)
        node.rpdo.read()
        node.tpdo.read()
        for _, pdo in maps_of(node.tpdo):         # our TPDOs are ours to send, not to hear
            if pdo.enabled:
                unsubscribe(self.network, pdo.cob_id, pdo.on_message)
        self.tpdo_last.clear()
        self.compile(node)

    def compile(self, node: canopen.LocalNode) -> None:
        """What each SYNC and step needs of the mapping, worked out once: the mapping
        changes only here (read at NMT start), while the PDOs go 100 times a second."""
        tpdos = maps_of(node.tpdo)
        self._on_sync_tpdos = [pdo for _, pdo in tpdos if pdo.enabled and pdo.trans_type
                               and 1 <= pdo.trans_type <= 240]
        self._on_change_tpdos = [(n, pdo) for n, pdo in tpdos if pdo.enabled and pdo.trans_type in (254, 255)]
        self._layouts = {id(pdo): PdoLayout.of(pdo, self.readers)
                         for _, pdo in maps_of(node.rpdo) + tpdos}

    def on_sync(self, node: canopen.LocalNode) -> None:
        """A SYNC: the TPDOs due at this count."""
        self._sync_count += 1
        for pdo in self._on_sync_tpdos:
            if self._sync_count % pdo.trans_type == 0:
                self.send(node, pdo)

    def _data(self, pdo: Any) -> bytes | None:
        """The mapped objects' bytes as node.get_data gives them, packed at once (None:
        a mapping `PdoLayout` does not cover)."""
        layout = self._layouts.get(id(pdo))
        return None if layout is None else layout.pack()

    def send(self, node: canopen.LocalNode, pdo: Any) -> bytes:
        data = self._data(pdo)
        if data is not None:
            pdo.data[:len(data)] = data
        else:
            mapped = [var for var in pdo if var.length]
            if any(var.offset % 8 or var.length % 8 for var in mapped):   # bit fields: canopen packs them
                for var in mapped:
                    var.set_data(node.get_data(var.index, var.subindex))
            else:           # whole bytes: one join, not canopen's per-variable packing
                data = b"".join([node.get_data(var.index, var.subindex) for var in mapped])
                pdo.data[:len(data)] = data
        self.network.send_message(pdo.cob_id, pdo.data)
        return bytes(pdo.data)

    def on_change(self, node: canopen.LocalNode) -> None:
        """A step: the TPDOs sent on change whose data changed."""
        if not self._on_change_tpdos or node.nmt.state != "OPERATIONAL":
            return
        for n, pdo in self._on_change_tpdos:
            data = self._data(pdo)
            if data is None:
                data = b"".join(node.get_data(v.index, v.subindex) for v in pdo if v.length)
            if self.tpdo_last.get(n) != data:
                self.tpdo_last[n] = self.send(node, pdo)
