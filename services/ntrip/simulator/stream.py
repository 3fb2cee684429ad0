"""The RTCM stream the caster twin sends one client: a batch of frames per epoch (the base's
next whole GPS second plus its latency, the station messages first), the client's GGA lines
read between them (a VRS mountpoint's virtual base stands where the first one says), and the
stream's faults, read from the caster at every step: `silent`, `drop_every_s`,
`flood_bytes_per_s`, `garbage_every_s`."""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import pynmea2

from viena.common import clock

from . import protocol, schedule
from .base import BaseStation
from .clients import TICK_S, Client, Closed, Sent, readable, send
from .mountpoint import Mountpoint

if TYPE_CHECKING:
    from .caster import CasterTwin

log = logging.getLogger(__name__)

MAX_LAG_EPOCHS = 5                # epochs a late client loop still sends; older ones are skipped
FLOOD_PERIOD_S = 0.1              # how often (timebase s) a flood sends its sub-second epochs


class RtcmStream:
    """One client's stream, from the answer's header to its end (a `Closed` says why)."""

    def __init__(self, caster: CasterTwin, client: Client, conn, mount: Mountpoint, v2: bool):
        self.caster, self.client, self.conn, self.mount, self.v2 = caster, client, conn, mount, v2
        self._first = True                             # the next batch leads with the station messages
        self._flood_t = self._next_flood = 0.0         # the flood sent up to _flood_t, next at _next_flood
        self._credit = 0.0                             # bytes the flood may still send
        self._next_garbage: float | None = None

    def run(self) -> None:
        client, tb = self.client, self.caster.timebase
        pending = client.request.rest if client.request else b""
        gga_header = client.request.headers.get("ntrip-gga") if client.request else None
        if gga_header:
            self._on_gga(gga_header)
        pending = self._read_lines(pending)
        start = tb.now()
        next_epoch = math.floor(start) + 1
        self._flood_t = self._next_flood = start
        while True:
            if client._kill:
                raise Closed(client._kill)
            now = tb.now()
            if self.caster.drop_every_s > 0 and now - start >= self.caster.drop_every_s:
                raise Closed(f"dropped by the caster after {now - start:.1f} s (drop_every_s)")
            send_at = next_epoch + self.mount.latency_s
            if now >= send_at:
                next_epoch = self._send_epoch(next_epoch, now)
                continue
            due = [send_at, *self._faults(now)]
            if self.caster.drop_every_s > 0:
                due.append(start + self.caster.drop_every_s)
            wait = min(tb.real_s(min(due) - now), TICK_S)
            if readable(self.conn, wait):
                data = self.conn.recv(4096)
                if not data:
                    raise Closed("closed by the client")
                pending = self._read_lines(pending + data)

    @property
    def frames(self) -> schedule.Frames | None:
        """Whose frames this client gets: the mountpoint's base, or (VRS) its own virtual
        base once its GGA came; None while a VRS client has sent none."""
        return self.mount.frames if not self.mount.vrs else self.client._frames

    def _send_epoch(self, epoch: int, now: float) -> int:
        """The frames of `epoch` (or, `MAX_LAG_EPOCHS` behind, of the newest); the next epoch."""
        behind = math.floor(now - self.mount.latency_s) - epoch
        if behind >= MAX_LAG_EPOCHS:
            epoch += behind
        frames = self.frames
        if frames is not None and not self.caster.silent:
            batch = frames.at(self.mount.messages, epoch, self._first)
            self._send_frames(batch, epoch)
            self._first = False
        return epoch + 1

    def _faults(self, now: float) -> list[float]:
        """The flood and the garbage due by `now` sent; when each is due next."""
        caster, due = self.caster, []
        if caster.flood_bytes_per_s > 0 and self.frames is not None and not caster.silent:
            if now >= self._next_flood:
                self._credit = min(self._credit + caster.flood_bytes_per_s * (now - self._flood_t),
                                   caster.flood_bytes_per_s)
                self._credit = self._flood(now)
                self._flood_t, self._next_flood = now, now + FLOOD_PERIOD_S
            due.append(self._next_flood)
        if caster.garbage_every_s > 0:
            if self._next_garbage is None:
                self._next_garbage = now + caster.garbage_every_s
            elif now >= self._next_garbage:
                self._garbage()
                self._next_garbage = now + caster.garbage_every_s
            due.append(self._next_garbage)
        else:
            self._next_garbage = None
        return due

    def _read_lines(self, data: bytes) -> bytes:
        """The client's upstream lines (GGA); what is left of a line not yet ended."""
        *lines, rest = data.split(b"\n")
        for raw in lines:
            line = raw.strip().decode("latin-1", "replace")
            if line:
                self._on_gga(line)
        return rest[-1024:]

    def _on_gga(self, line: str) -> None:
        if "GGA" not in line[:7]:
            return
        client, mount = self.client, self.mount
        client.gga.append(line)
        if not mount.vrs or client.base is not None:
            return
        try:
            gga = pynmea2.parse(line)
            if not int(gga.gps_qual or 0) or gga.latitude is None:
                return
            height = float(gga.altitude or 0.0) + float(gga.geo_sep or 0.0)
        except (pynmea2.ParseError, ValueError, TypeError, AttributeError):
            return
        base = mount.base
        client.base = BaseStation(gga.latitude, gga.longitude, height, station_id=base.station_id,
                                  seed=base.seed, systems=base.systems, descriptors=base.descriptors)
        client._frames = schedule.Frames(client.base)
        log.info("client %d: a virtual base at %.5f, %.5f", client.id, gga.latitude, gga.longitude)

    def _send_frames(self, batch: list[tuple[int, bytes]], epoch: float) -> None:
        if not batch:
            return
        data = b"".join(f for _, f in batch)
        self._record([Sent(n, float(epoch), clock.monotonic()) for n, _ in batch])
        self._send(data)

    def _record(self, records: list[Sent]) -> None:
        """Frames about to be handed to the socket: that instant is their send time."""
        self.client.sent.extend(records)
        self.caster.sent.extend(records)

    def _flood(self, now: float) -> float:
        """Observables of sub-second epochs between the flood's last send and `now`, as many
        bytes as its credit holds (a base streaming far faster than 1 Hz); the credit left."""
        frames, credit, flood_t = self.frames, self._credit, self._flood_t
        number = next((n for n in self.mount.messages if n in schedule.OBSERVABLES), None)
        if number is None or frames is None:
            return 0.0
        size = len(frames.frame(number, float(math.floor(now))))
        count = int(credit // size)
        if count == 0:
            return credit
        step = (now - flood_t) / count
        batch, epochs = [], []
        for k in range(1, count + 1):
            epoch = round(flood_t + k * step, 3)
            batch.append((number, frames.frame(number, epoch)))
            epochs.append(epoch)
            credit -= size
        data = b"".join(f for _, f in batch)
        sent_at = clock.monotonic()
        self._record([Sent(n, e, sent_at) for (n, _), e in zip(batch, epochs)])
        self._send(data)
        self.client.flood_bytes += len(data)
        return credit

    def _garbage(self) -> None:
        """Bytes that are no RTCM (no 0xD3 preamble among them) between two frames."""
        rng = self.caster.rng
        size = int(rng.integers(16, 65))
        values = rng.integers(0, 255, size)
        self._send(bytes(int(v) + (v >= 0xD3) for v in values))
        self.client.garbage_bytes += size
        self.caster.garbage_bytes_sent += size

    def _send(self, data: bytes) -> None:
        send(self.client, self.conn, protocol.chunk(data) if self.v2 else data)
