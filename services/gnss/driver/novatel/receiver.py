"""A NovAtel OEM4 receiver on a serial URL: commands with matched responses, logs out.

Usable from a Python shell::

    from viena.services.gnss.driver import NovatelReceiver, StartupConfig
    rx = NovatelReceiver("socket://127.0.0.1:5000")
    rx.startup(StartupConfig())          # 9600, break, UNLOGALL, COM 115200, ... LOG BESTXYZ
    msg = rx.read(timeout=1.0)           # LogMessage(header, BestXyz(...), t_host_ns)
    rx.shutdown()

Each command waits for the response carrying its own message ID (response bit set), so a
response can never be taken for the next command's (the old library's desync); a
rejection raises CommandError with the receiver's text, silence raises CommandTimeout.

With ``StartupConfig(read_config=True)`` the start-up ends by asking for RXCONFIG in ASCII:
the receiver lists every setting it holds, enumerations by name, and ``config`` keeps the
latest of each (``sbas()`` is SBASCONTROL's), so what the receiver does can be checked
against what was asked in the receiver's own words.

With ``ask_version`` it asks for VERSION once (``version``, ``ability``: the model, firmware
and the correction formats they take, corrections.py); with a ``corrections`` format it then
configures the receiver to take them (DGPSTIMEOUT, RTKSOURCE, PSRDIFFSOURCE, INTERFACEMODE),
or refuses a format the receiver cannot take (``corrections_refused`` says why, and the
receiver keeps its single-point solution). On the logs' own port INTERFACEMODE is the very
last command: the port then reads only corrections, until a break (the next start-up's)
puts it back to NOVATEL NOVATEL. ``write_corrections`` sends the bytes.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

import serial

from viena.common import clock
from viena.common.link import open_link
from viena.common.link_reader import LinkReader

from .ascii import AsciiError, ConfigEntry, config_entry, message_of
from .commands import (
    BodyError,
    Com,
    Command,
    CommandError,
    CommandTimeout,
    DynamicsCommand,
    Log,
    Reset,
    Response,
    SaveConfig,
    SbasControl,
    Unlog,
    Unlogall,
    sbas_keyword_value,
)
from .corrections import ReceiverAbility, ability_of_version
from .enums import (
    Dynamics,
    MessageFormat,
    MessageId,
    Port,
    SbasKeyword,
    SbasSystem,
    SbasTestMode,
    Trigger,
)
from .framing import MAX_BODY_LENGTH, AsciiFrame, DecoderStats, Frame, FrameDecoder
from .logs import LogMessage, Version, decode_log
from .startup import StartupConfig, run_startup

log = logging.getLogger(__name__)

#: Port reset by break (COM command, docs/sensors.md#start-up-sequence): two 250 ms breaks 1.5 s apart, then
#: at least 250 ms of quiet.
BREAK_S = 0.25
BREAK_GAP_S = 1.5
BREAK_SETTLE_S = 0.25


@dataclass
class ReceiverStats(DecoderStats):
    """Decoder counters plus what happened above the framing."""

    logs: int = 0
    responses: int = 0
    unmatched_responses: int = 0    # a response no command was waiting for
    unknown_messages: int = 0       # good CRC, message ID this driver does not decode
    body_errors: int = 0            # good CRC, body size wrong for its message ID
    command_failures: int = 0       # rejected or unanswered commands
    dropped_logs: int = 0           # read() queue full: nobody is reading
    config_logs: int = 0            # RXCONFIG logs (one per setting)


class _Pending:
    __slots__ = ("message_id", "event", "response")

    def __init__(self, message_id: int):
        self.message_id = message_id
        self.event = clock.Event()
        self.response: Response | None = None


class NovatelReceiver:
    """Binary OEM4 receiver on a serial URL (any `open_link` takes).

    ``on_log(LogMessage)`` is called from the reader thread for every decoded log; without
    it, logs queue up for ``read()``. ``on_link_error(exc)`` reports a port that failed.
    """

    def __init__(self, url: str, *, command_timeout: float = 1.0,
                 on_log: Callable[[LogMessage], None] | None = None,
                 on_link_error: Callable[[Exception], None] | None = None,
                 max_body_length: int = MAX_BODY_LENGTH, queue_size: int = 1000):
        self.url = url
        self.command_timeout = command_timeout
        self._on_log = on_log
        self._on_link_error = on_link_error
        self._decoder = FrameDecoder(max_body_length)
        self.stats = ReceiverStats()
        self._logs = clock.Queue(maxsize=queue_size)    # of LogMessage
        self._link = open_link(url)
        self._reader = LinkReader(self._link, self._on_bytes, self._on_error, name="novatel")
        # one command at a time; held across the wait for the response, so it is a clock
        # queue of one token (a thread waiting for it parks on a virtual clock, where a
        # threading.Lock would hold the whole simulation up)
        self._command_slot = clock.Queue(maxsize=1)
        self._pending: _Pending | None = None
        self._state_lock = threading.Lock()
        self.last_frame_host_ns = 0
        #: the receiver's settings as its last RXCONFIG listed them, by command name
        self.config: dict[str, ConfigEntry] = {}
        #: why the RXCONFIG request of the last start-up failed ("" if it did not)
        self.config_request_error = ""
        #: the receiver's VERSION log (kept across start-ups: the same receiver), what its
        #: model and firmware take, and why the last request for it failed
        self.version: Version | None = None
        self.ability: ReceiverAbility | None = None
        self.version_error = ""
        self._version_event = clock.Event()
        #: the corrections format the last start-up configured ("" none) ...
        self.corrections_format = ""
        #: ... or why it refused the one asked for ("" if it did not): "model 3151R firmware ..."
        self.corrections_refused = ""
        #: the logs' port's INTERFACEMODE went unanswered: taken as switched (firmware may
        #: switch before it answers), not known to be; a differential fix confirms it
        self.corrections_unconfirmed = False

    # -- port ------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._link.is_open

    @property
    def carries_break(self) -> bool:
        """Whether the port can send a break (not socket://)."""
        return self._link.carries_break

    def open(self, baudrate: int = 9600) -> None:
        self._reader.stop()           # an old reader must not see its port close
        self._decoder.reset()
        self.config = {}              # what another connection read may no longer hold
        self.config_request_error = ""
        self.corrections_format = ""  # a new connection's port starts NOVATEL NOVATEL
        self.corrections_unconfirmed = False
        self._link.open(baudrate)
        self._reader.start()

    def close(self) -> None:
        """Close the port; a command waiting for its response gives up at once."""
        with self._state_lock:
            pending = self._pending
        if pending is not None:
            pending.event.set()
        self._reader.stop()
        self._link.close()

    def __enter__(self) -> NovatelReceiver:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- commands --------------------------------------------------------------------
    def command(self, cmd: Command, timeout: float | None = None) -> Response:
        """Send a command and wait for its response; OK returns it, anything else raises
        CommandError (with the receiver's text), silence raises CommandTimeout."""
        timeout = self.command_timeout if timeout is None else timeout
        self._command_slot.put(None)
        try:
            pending = _Pending(cmd.MESSAGE_ID)
            with self._state_lock:
                self._pending = pending
            try:
                self._link.write(cmd.frame())
                answered = pending.event.wait(timeout)
            finally:
                with self._state_lock:
                    self._pending = None
        finally:
            self._command_slot.get_nowait()
        if not answered:
            self.stats.command_failures += 1
            raise CommandTimeout(f"{cmd.name}: no response within {timeout:.2f} s")
        response = pending.response
        if response is None:
            raise serial.SerialException(f"{cmd.name}: port closed while waiting for the response")
        if not response.ok:
            self.stats.command_failures += 1
            raise CommandError(cmd.name, response.response_id, response.text)
        return response

    def log(self, message: MessageId | int, trigger: Trigger = Trigger.ONTIME,
            period: float = 0.0, offset: float = 0.0, hold: bool = False,
            port: Port = Port.THISPORT, fmt: MessageFormat = MessageFormat.BINARY) -> Response:
        """LOG; `fmt` ASCII asks for the log in ASCII (bits 5-6 of its message type)."""
        return self.command(Log(port=port, message=message, message_type=int(fmt) << 5,
                                trigger=trigger, period=period, offset=offset, hold=int(hold)))

    def unlog(self, message: MessageId | int, port: Port = Port.THISPORT) -> Response:
        return self.command(Unlog(port=port, message=message))

    def unlogall(self, port: Port = Port.THISPORT_ALL, held: bool = True,
                 timeout: float | None = None) -> Response:
        return self.command(Unlogall(port=port, held=int(held)), timeout)

    def com(self, baud: int, **settings) -> Response:
        """COM on this port; the host's own rate is left to the caller (see set_baud)."""
        return self.command(Com(baud=baud, **settings))

    def dynamics(self, dynamics: Dynamics = Dynamics.AIR) -> Response:
        return self.command(DynamicsCommand(dynamics))

    def sbascontrol(self, keyword: SbasKeyword = SbasKeyword.ENABLE,
                    system: SbasSystem = SbasSystem.AUTO, prn: int = 0,
                    testmode: SbasTestMode = SbasTestMode.NONE,
                    enable_value: int = SbasKeyword.ENABLE) -> Response:
        """SBASCONTROL, its keyword sent as `enable_value` for ENABLE (the other for DISABLE)."""
        return self.command(SbasControl(sbas_keyword_value(keyword, enable_value), system, prn,
                                        testmode))

    def sbas(self) -> ConfigEntry | None:
        """SBASCONTROL as the receiver's last RXCONFIG listed it (fields: keyword, system,
        prn, testmode, by name), or None before one came."""
        return self.config.get("SBASCONTROL")

    def reset(self, delay: int = 0) -> Response:
        return self.command(Reset(delay))

    def saveconfig(self) -> Response:
        return self.command(SaveConfig())

    def set_baud(self, baudrate: int) -> None:
        """Change the host side's rate of the open port."""
        self._link.set_baudrate(baudrate)

    # -- the car's sequences ---------------------------------------------------------
    def startup(self, config: StartupConfig | None = None) -> None:
        """Open (if needed) and configure the receiver the way the car does (startup.py;
        StartupConfig() without one)."""
        run_startup(self, StartupConfig() if config is None else config)

    def request_version(self, timeout_s: float = 1.0) -> Version | None:
        """LOG VERSION ONCE and wait for it: `version` and `ability` (what its model and
        firmware take). A receiver that refuses or does not send it is still a working
        receiver: `version_error` says why, and the last VERSION read is kept."""
        self._version_event.clear()
        try:
            self.log(MessageId.VERSION, Trigger.ONCE)
        except (CommandError, CommandTimeout) as exc:
            self.version_error = str(exc)
            return None
        if not self._version_event.wait(timeout_s):
            self.version_error = f"no VERSION log within {timeout_s:.1f} s of its LOG's answer"
            return None
        self.version_error = ""
        return self.version

    def reset_port_by_break(self) -> None:
        """Two breaks and a quiet spell: the port back to its factory rate and modes (COM §2.6.10)."""
        self._link.send_break(BREAK_S)
        clock.sleep(BREAK_GAP_S)
        self._link.send_break(BREAK_S)
        clock.sleep(BREAK_SETTLE_S)

    def write_corrections(self, data: bytes) -> None:
        """Send correction bytes on this port (whole frames: the link's write lock keeps a
        command's frame out of them); SerialException or OSError when the port is gone."""
        self._link.write(data)

    def shutdown(self, timeout: float = 0.5) -> None:
        """Stop the logs (best effort) and close the port."""
        if self.is_open:
            try:
                self.unlogall(Port.THISPORT_ALL, timeout=timeout)
            except (CommandError, CommandTimeout, serial.SerialException, OSError) as exc:
                log.info("%s: UNLOGALL at shutdown failed: %s", self.url, exc)
        self.close()

    # -- logs ------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> LogMessage:
        """Next decoded log (when no on_log callback is set); queue.Empty on timeout."""
        return self._logs.get(timeout=timeout)

    # -- reader thread ---------------------------------------------------------------
    def _on_bytes(self, data: bytes, t_host_ns: int) -> None:
        for frame in self._decoder.feed(data, t_host_ns):
            self.last_frame_host_ns = t_host_ns
            if isinstance(frame, AsciiFrame):
                self._on_ascii(frame)
            else:
                self._dispatch(frame)
        self._sync_decoder_stats()

    def _on_ascii(self, frame: AsciiFrame) -> None:
        """ASCII logs: RXCONFIG's settings are kept; nothing else is asked for in ASCII."""
        try:
            entry = config_entry(message_of(frame))
        except AsciiError as exc:
            self.stats.unknown_messages += 1
            log.debug("%s: ASCII message not used: %s", self.url, exc)
            return
        self.stats.config_logs += 1
        self.config[entry.command] = entry

    def _dispatch(self, frame: Frame) -> None:
        stats = self.stats
        if frame.header.is_response:
            try:
                response = Response.from_body(frame.body)
            except BodyError as exc:
                stats.body_errors += 1
                log.warning("%s: bad response frame: %s", self.url, exc)
                return
            stats.responses += 1
            with self._state_lock:
                pending = self._pending
                if pending is not None and pending.message_id == frame.header.message_id:
                    pending.response = response
                    pending.event.set()
                    return
            stats.unmatched_responses += 1
            log.info("%s: response to %s nobody waited for: %s", self.url,
                     MessageId(frame.header.message_id).name, response.text)
            return
        if frame.header.message_id == MessageId.VERSION:
            self._on_version(frame)
            return
        try:
            message = decode_log(frame)
        except BodyError as exc:
            stats.body_errors += 1
            log.warning("%s: %s", self.url, exc)
            return
        if message is None:
            stats.unknown_messages += 1
            return
        stats.logs += 1
        if self._on_log is not None:
            self._on_log(message)
            return
        try:
            self._logs.put_nowait(message)
        except clock.Full:
            stats.dropped_logs += 1

    def _on_version(self, frame: Frame) -> None:
        try:
            version = Version.from_body(frame.body)
        except BodyError as exc:
            self.stats.body_errors += 1
            log.warning("%s: %s", self.url, exc)
            return
        self.version, self.ability = version, ability_of_version(version)
        self._version_event.set()

    def _sync_decoder_stats(self) -> None:
        d = self._decoder.stats
        s = self.stats
        s.frames, s.crc_errors, s.length_errors = d.frames, d.crc_errors, d.length_errors
        s.resyncs, s.discarded_bytes = d.resyncs, d.discarded_bytes
        s.ascii_messages = d.ascii_messages

    def _on_error(self, exc: Exception) -> None:
        log.warning("%s: port failed: %s", self.url, exc)
        if self._on_link_error is not None:
            self._on_link_error(exc)
