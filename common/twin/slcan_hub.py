"""A serial CAN adapter on TCP: the slcan (LAWICEL) ASCII protocol, bridged to a CAN bus.

Processes that drive CAN devices open python-can's own `slcan` interface with the channel
`socket://127.0.0.1:PORT`, exactly as they would open a USB-serial adapter such as a
CANable (`/dev/ttyACM0`). The hub answers like that adapter: it acknowledges commands with
CR (BEL for errors), opens and closes the channel on `O`/`L`/`C`, reports a version on
`V`, and carries frames as `tiiildd..` / `Tiiiiiiiildd..` / `riiil` / `Riiiiiiiil`.

Every connected client is a node on one bus: a frame sent by one client reaches every
other open client and the in-process python-can `virtual` channel where simulated nodes
(the EPOS twin's canopen LocalNode) live; frames from that channel reach every client.
As on a real bus a sender does not hear its own frame, a closed channel (`C`) neither
sends nor receives, a listen-only channel (`L`) receives only, and a client set to a
different bitrate than the bus hears nothing and is heard by no one.

As a USB adapter, the hub hands a client what it has at one moment in one write: the
acknowledgements of a client's frames wait up to one USB frame (1 ms) for the frames the
bus answers with (the TPDOs a SYNC brings), and frames that went by together (TPDO1 and
TPDO2) go together. A host then wakes once a SYNC period, not three times.

As on a real bus, anyone plugged in may talk: a CAN monitor beside the steering service is
one more client. Plugged in means, on loopback, a process of the hub's own user
(peers.py); others are refused, with a log line.
"""
from __future__ import annotations

import logging
import selectors
import socket
import threading
import time

import can

from viena.common.log import Throttled
from viena.common.twin.peers import refusal

log = logging.getLogger(__name__)

OK = b"\r"
ERROR = b"\a"
#: slcan bitrate commands S0..S8, as python-can's slcanBus sends them
BITRATES = {"S0": 10_000, "S1": 20_000, "S2": 50_000, "S3": 100_000, "S4": 125_000,
            "S5": 250_000, "S6": 500_000, "S7": 750_000, "S8": 1_000_000, "S9": 83_300}
HW_VERSION = "V1013"          # what a LAWICEL CAN232 / CANable says to `V`
SERIAL_NUMBER = "NVIEN"
MAX_LINE = 64                 # longest valid slcan line is 27 characters (T + 8 + 1 + 16 + ts)
#: a USB adapter answers in the host's next USB transfer: the acknowledgements of a client's
#: frames wait this long for what the bus answers them with, to go in one write together
USB_FRAME_S = 0.001


class SlcanError(ValueError):
    """A line the adapter does not understand: answered with BEL."""


def parse_frame(line: str) -> can.Message:
    """A `t`/`T`/`r`/`R` line (without CR) as a python-can Message."""
    kind = line[:1]
    extended = kind in ("T", "R")
    id_len = 8 if extended else 3
    try:
        can_id = int(line[1:1 + id_len], 16)
        dlc = int(line[1 + id_len], 16)
    except (ValueError, IndexError):
        raise SlcanError(f"bad frame header {line!r}") from None
    if dlc > 8 or can_id > (0x1FFFFFFF if extended else 0x7FF) or len(line[1:1 + id_len]) != id_len:
        raise SlcanError(f"bad id or length in {line!r}")
    remote = kind in ("r", "R")
    data = b""
    if not remote:
        hexdata = line[2 + id_len:2 + id_len + 2 * dlc]
        if len(hexdata) != 2 * dlc:
            raise SlcanError(f"frame {line!r} is shorter than its length {dlc}")
        try:
            data = bytes.fromhex(hexdata)
        except ValueError:
            raise SlcanError(f"bad data in {line!r}") from None
    return can.Message(arbitration_id=can_id, is_extended_id=extended, is_remote_frame=remote,
                       dlc=dlc, data=data)


def format_frame(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """A python-can Message as one slcan line with its CR."""
    if msg.is_remote_frame:
        head = f"R{msg.arbitration_id:08X}" if msg.is_extended_id else f"r{msg.arbitration_id:03X}"
        line = f"{head}{msg.dlc:d}"
    else:
        head = f"T{msg.arbitration_id:08X}" if msg.is_extended_id else f"t{msg.arbitration_id:03X}"
        line = f"{head}{len(msg.data):d}{bytes(msg.data).hex().upper()}"
    if timestamp_ms is not None:
        line += f"{timestamp_ms % 60000:04X}"
    return line.encode("ascii") + OK


class _Client:
    """One connected host: its socket, its half-read line and its channel settings."""

    def __init__(self, sock: socket.socket, peer, bus_bitrate: int):
        self.sock = sock
        self.peer = peer
        self.buffer = bytearray()
        self.open = False
        self.listen_only = False
        self.timestamps = False
        self.bitrate = bus_bitrate
        self.bus_bitrate = bus_bitrate
        self.send_lock = threading.Lock()
        self.owed = bytearray()              # acknowledgements held for the next write (send_lock)
        self.owed_until = 0.0                # when they go on their own (0: nothing held)
        self.alive = True

    @property
    def hears(self) -> bool:
        return self.alive and self.open and self.bitrate == self.bus_bitrate

    @property
    def talks(self) -> bool:
        return self.hears and not self.listen_only


class SlcanHub:
    """Serves a CAN bus to slcan clients on TCP; see the module docstring.

    `channel` names the python-can `virtual` channel shared with in-process nodes.
    """

    def __init__(self, channel: str, host: str = "127.0.0.1", port: int = 0,
                 bitrate: int = 1_000_000):
        self.channel = channel
        self.bitrate = bitrate
        self._server = socket.create_server((host, port))
        self._server.setblocking(False)
        self.host, self.port = self._server.getsockname()[:2]
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._clients: list[_Client] = []
        self._clients_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._serve, name=f"slcan-hub-{self.port}", daemon=True),
            threading.Thread(target=self._from_bus, name=f"slcan-bus-{self.port}", daemon=True),
        ]
        self._t0 = time.monotonic()
        self.frames_from_clients = 0
        self.frames_to_clients = 0
        self.frames_dropped = 0
        self.refused = 0                      # connections closed unserved
        self._refused = Throttled(log, f"slcan hub {self.port}: connection refused")

    @property
    def url(self) -> str:
        """What a host passes as python-can slcan `channel`."""
        return f"socket://{self.host}:{self.port}"

    @property
    def clients(self) -> int:
        with self._clients_lock:
            return sum(1 for c in self._clients if c.alive)

    def start(self) -> SlcanHub:
        for t in self._threads:
            t.start()
        log.info("slcan hub on %s bridged to virtual channel %r", self.url, self.channel)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            if t.is_alive():
                t.join(timeout=2)
        with self._clients_lock:
            clients, self._clients = self._clients, []
        for c in clients:
            c.alive = False
            c.sock.close()
        self._server.close()
        self._bus.shutdown()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- the TCP side ---------------------------------------------------------------------
    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._server, selectors.EVENT_READ)
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(self._flush_owed()):
                    if key.fileobj is self._server:
                        self._accept(sel)
                    else:
                        self._read(sel, key.data)
        finally:
            sel.close()

    def _accept(self, sel) -> None:
        try:
            sock, peer = self._server.accept()
        except BlockingIOError:
            return
        why = refusal(sock)
        if why is not None:
            self.refused += 1                 # counted before the peer can see it closed
            self._refused.log(why, f"from {peer[0]}:{peer[1]}")
            sock.close()
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(0.5)           # a stuck client is dropped, not waited on
        client = _Client(sock, peer, self.bitrate)
        with self._clients_lock:
            self._clients.append(client)
        sel.register(sock, selectors.EVENT_READ, client)
        log.info("slcan client %s:%s connected", *peer[:2])

    def _read(self, sel, client: _Client) -> None:
        try:
            data = client.sock.recv(4096)
        except (TimeoutError, BlockingIOError):
            return
        except OSError:
            data = b""
        if not data or not client.alive:
            sel.unregister(client.sock)
            self._drop(client, "disconnected")
            client.sock.close()
            return
        client.buffer.extend(data)
        replies = bytearray()
        sent: list[can.Message] = []
        while True:
            end = _line_end(client.buffer)
            if end < 0:
                if len(client.buffer) > MAX_LINE:        # garbage without a CR: resync
                    client.buffer.clear()
                    replies += ERROR
                break
            line = client.buffer[:end].decode("ascii", "replace").strip("\n")
            del client.buffer[:end + 1]
            replies += self._command(client, line, sent)
        if replies:
            # only acknowledgements of frames: they wait a USB frame for the bus's answers
            self._send(client, bytes(replies), hold=len(replies) == 2 * len(sent) > 0)   # acks alone: z\r each
        if sent:                                         # the acks, the frames, then what answers them
            self._to_clients(sent, exclude=client)
            for msg in sent:
                self._deliver(msg)

    def _command(self, client: _Client, line: str, sent: list[can.Message]) -> bytes:
        """Execute one slcan command; the reply bytes. A frame is added to `sent`, for the
        other clients and then the bus's own nodes (`_on_client_data`)."""
        cmd = line[:1]
        if cmd in ("t", "T", "r", "R"):
            if not client.talks:
                self.frames_dropped += 1
                return ERROR if not client.open or client.listen_only else (b"z\r" if cmd in "tr" else b"Z\r")
            try:
                msg = parse_frame(line)
            except SlcanError as exc:
                log.debug("client %s: %s", client.peer, exc)
                return ERROR
            sent.append(msg)
            return b"z\r" if cmd in ("t", "r") else b"Z\r"
        if cmd == "O":
            client.open, client.listen_only = True, False
            return OK
        if cmd == "L":
            client.open, client.listen_only = True, True
            return OK
        if cmd == "C":
            client.open = False
            return OK
        if cmd == "S":
            if client.open or line not in BITRATES:
                return ERROR
            client.bitrate = BITRATES[line]
            if client.bitrate != self.bitrate:
                log.warning("slcan client %s set %d bit/s on a %d bit/s bus: it will hear nothing",
                            client.peer, client.bitrate, self.bitrate)
            return OK
        if cmd == "s":                   # BTR registers: only valid while closed
            return ERROR if client.open else OK
        if cmd == "V":
            return HW_VERSION.encode() + OK
        if cmd == "v":
            return b"v" + HW_VERSION[1:].encode() + OK
        if cmd == "N":
            return SERIAL_NUMBER.encode() + OK
        if cmd == "F":
            return b"F00" + OK
        if cmd == "Z":
            client.timestamps = line[1:2] == "1"
            return OK
        if cmd in ("M", "m", "X", "W", "Q", "U", ""):
            return OK
        return ERROR

    # -- the bus -------------------------------------------------------------------------
    def _deliver(self, msg: can.Message) -> None:
        """A client's frame on the wire: the in-process nodes hear it now (the other
        clients once the client's write is read through: `_read`)."""
        self.frames_from_clients += 1
        try:
            self._bus.send(msg)
        except can.CanError as exc:
            log.warning("virtual bus refused a frame: %s", exc)

    def _from_bus(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=0.1)
                msgs = []
                while msg is not None:           # and what came with it (TPDO1 and TPDO2 on a SYNC)
                    msgs.append(msg)
                    msg = self._bus.recv(timeout=0)
            except can.CanError:
                break
            if msgs:
                self._to_clients(msgs, exclude=None)

    def _to_clients(self, msgs: list[can.Message], exclude: _Client | None) -> None:
        """Frames that went by at one moment, to every client that hears them: in one write
        each, as a USB adapter hands over back-to-back frames in one transfer."""
        with self._clients_lock:
            targets = [c for c in self._clients if c is not exclude and c.hears]
        if not targets:
            return
        plain = b"".join(format_frame(msg) for msg in msgs)
        for c in targets:
            if c.timestamps:
                ms = self._ms()
                data = b"".join(format_frame(msg, ms) for msg in msgs)
            else:
                data = plain
            if self._send(c, data):
                self.frames_to_clients += len(msgs)

    def _ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000)

    def _send(self, client: _Client, data: bytes, hold: bool = False) -> bool:
        """`data` to the client after what it is owed, in one write; or, `hold`, owed too."""
        try:
            with client.send_lock:
                if hold:
                    client.owed += data
                    client.owed_until = client.owed_until or time.monotonic() + USB_FRAME_S
                    return True
                if client.owed:
                    data, client.owed_until = bytes(client.owed) + data, 0.0
                    client.owed.clear()
                if data:
                    client.sock.sendall(data)
            return True
        except OSError as exc:
            self._drop(client, f"send failed ({exc})")
            return False

    def _flush_owed(self) -> float:
        """Send what is owed past its USB frame; seconds until the next is due (at most 0.1)."""
        with self._clients_lock:
            owing = [c for c in self._clients if c.owed_until]
        wait, now = 0.1, time.monotonic()
        for c in owing:
            due = c.owed_until
            if not due:
                continue                         # sent meanwhile, with frames
            if due <= now:
                self._send(c, b"")
            else:
                wait = min(wait, due - now)
        return wait

    def _drop(self, client: _Client, why: str) -> None:
        """Forget a client; its socket is shut down here and closed by the serving thread,
        which owns the selector it is registered with."""
        if not client.alive:
            return
        client.alive = False
        with self._clients_lock:
            if client in self._clients:
                self._clients.remove(client)
        try:
            client.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        log.info("slcan client %s:%s %s", *client.peer[:2], why)


def _line_end(buffer: bytearray) -> int:
    """Index of the first CR (or LF, which some terminals send), or -1."""
    cr = buffer.find(b"\r")
    lf = buffer.find(b"\n")
    ends = [i for i in (cr, lf) if i >= 0]
    return min(ends) if ends else -1
