"""The NovAtel twin's command interpreter: binary frames in, each checked as the receiver
checks it (CRC, ID, body size, each field against its table: vol. 2 chapter 2 and Table 7's
responses), applied to the twin's settings, and answered on the port it came on.

A handler returns what is to happen after the response goes out (a new rate, a polled log),
or None.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

from viena.services.gnss.driver.novatel import commands as cmds
from viena.services.gnss.driver.novatel import enums
from viena.services.gnss.driver.novatel.framing import (
    CRC_LENGTH,
    HEADER_LENGTH,
    MAX_BODY_LENGTH,
    SYNC,
    Header,
    crc32,
    encode_frame,
    unpack_header,
)
from viena.services.gnss.driver.novatel.logs import Version

from .novatel_logs import LOG_MAKERS, MAX_LOGS, MIN_PERIOD_MS, LogEntry, ReceiverConfig
from .novatel_rxconfig import rxconfig_logs
from .ports import ReceiverPort
from .rtk import Source

if TYPE_CHECKING:
    from .novatel_twin import NovatelTwin

OWN_PORT = enums.Port.COM1
OWN_UNLOGALL = (enums.Port.THISPORT_ALL, enums.Port.ALL_PORTS, enums.Port.COM1_ALL)


class Rejected(Exception):
    """A command the receiver refuses, with its response ID and text argument."""

    def __init__(self, response_id: enums.ResponseId, arg=None):
        self.response_id = enums.ResponseId(response_id)
        self.text = enums.RESPONSE_TEXT.get(self.response_id, self.response_id.name).format(arg)


class CommandInterpreter:
    """The receiver's command side, one per twin: `parse` takes a port's input."""

    def __init__(self, twin: NovatelTwin):
        self.twin = twin
        self._cmd_port = twin.com1                  # the port the command in hand came on

    def parse(self, now_s: float, port: ReceiverPort) -> None:
        """Take complete frames off the input as the receiver does: a frame is as long as
        its header says, and its CRC decides whether it is executed or refused. Stops when a
        command took the port's commands away (INTERFACEMODE): the rest is not for it."""
        buf = port.rx
        while port.takes_commands:
            start = buf.find(SYNC)
            if start < 0:
                del buf[:max(0, len(buf) - 2)]
                return
            del buf[:start]
            if len(buf) < HEADER_LENGTH:
                return
            header = unpack_header(buf)
            if header.header_length < HEADER_LENGTH or header.length > MAX_BODY_LENGTH:
                del buf[:1]
                continue
            total = header.header_length + header.length + CRC_LENGTH
            if len(buf) < total:
                return
            frame = bytes(buf[:total])
            del buf[:total]
            if crc32(frame[:-CRC_LENGTH]) != int.from_bytes(frame[-CRC_LENGTH:], "little"):
                self.twin.checksum_errors += 1
                self._respond(header, now_s, Rejected(enums.ResponseId.INVALID_CHECKSUM), port)
                continue
            if header.is_response or header.message_format != 0:
                continue                        # only binary commands are understood
            self._execute(header, frame[header.header_length:-CRC_LENGTH], now_s, port)

    def _respond(self, header: Header, now_s: float, result: Rejected | None, port: ReceiverPort) -> None:
        response = (cmds.Response(enums.ResponseId.OK, "OK") if result is None
                    else cmds.Response(result.response_id, result.text))
        self.twin.history.append((enums.MessageId(header.message_id).name, response.text))
        if not port.responses:
            return                              # INTERFACEMODE ... OFF: no responses on this port
        out = self.twin.output.header(header.message_id, self.twin._gps_ms(now_s),
                           message_type=header.message_type, sequence=header.sequence, port_address=port.address)
        port.out += response.frame(out)

    def _execute(self, header: Header, body: bytes, now_s: float, port: ReceiverPort) -> None:
        cls = cmds.COMMANDS.get(header.message_id)
        after = None
        self._cmd_port = port
        try:
            if cls is None:
                raise Rejected(enums.ResponseId.INVALID_MESSAGE_ID)
            try:
                command = cls.from_body(body)
            except cmds.BodyError:
                raise Rejected(enums.ResponseId.MESSAGE_MISSING_FIELD) from None
            after = self._HANDLERS[cls](self, command, now_s)
        except Rejected as rejected:
            self._respond(header, now_s, rejected, port)
            return
        self._respond(header, now_s, None, port)
        if after is not None:
            after()

    def _on_com1(self, port: int) -> bool:
        """Whether a LOG/UNLOG port field names COM1, where this twin's logs come out."""
        return port == OWN_PORT or (port == enums.Port.THISPORT and self._cmd_port is self.twin.com1)

    def _com_port(self, com: int) -> ReceiverPort | None:
        """The port a COM or INTERFACEMODE port field (Table 15) names, if the twin has it."""
        if com == enums.ComPort.THISPORT:
            return self._cmd_port
        return self.twin.ports.get(com)

    def _log_port(self, port: int) -> ReceiverPort | None:
        """The port a LOG port field (Table 5) sends a polled log to, if the twin has it."""
        if port == enums.Port.THISPORT:
            return self._cmd_port
        return next((p for p in self.twin.ports.values() if p.address == port), None)

    @staticmethod
    def _check(field_no: int, ok: bool, response=enums.ResponseId.INVALID_MESSAGE_FIELD) -> None:
        if not ok:
            raise Rejected(response, field_no)

    def _known(self, value) -> bool:
        return not value.name.startswith("UNKNOWN_")

    def _log(self, cmd: cmds.Log, now_s: float):
        self._check(2, self._known(cmd.port))
        if cmd.message == enums.MessageId.RXCONFIG:
            return self._rxconfig(cmd, now_s)
        if cmd.message == enums.MessageId.VERSION:
            return self._version(cmd, now_s)
        if cmd.message not in LOG_MAKERS:
            raise Rejected(enums.ResponseId.LOG_DOES_NOT_EXIST)
        self._check(4, (cmd.message_type >> 5) & 0x3 == 0)       # the twin speaks binary
        self._check(6, self._known(cmd.trigger))
        self._check(7, math.isfinite(cmd.period) and cmd.period >= 0.0,
                    enums.ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(9, cmd.hold in (0, 1))
        period_ms = max(MIN_PERIOD_MS, int(round(cmd.period * 1000.0)))
        if cmd.trigger == enums.Trigger.ONTIME:
            self._check(7, cmd.period > 0.0, enums.ResponseId.PARAMETER_OUT_OF_RANGE)
            if not (math.isfinite(cmd.offset) and 0.0 <= cmd.offset < max(cmd.period, 0.05)):
                raise Rejected(enums.ResponseId.INVALID_OFFSET)
        if not self._on_com1(cmd.port):
            return None                         # logged on another port: not ours to send
        message = enums.MessageId(cmd.message)
        if message not in self.twin.logs and len(self.twin.logs) >= MAX_LOGS:
            raise Rejected(enums.ResponseId.NOT_ENOUGH_RESOURCES)
        trigger = enums.Trigger(cmd.trigger)
        if self.twin.replay is None:
            after_ms = self.twin._gps_ms(now_s)
        else:
            if not self.twin.replay.started and trigger not in (enums.Trigger.ONCE, enums.Trigger.ONMARK):
                self.twin.output.begin_replay(now_s)
            after_ms = -1 if self.twin.replay.last is None else self.twin.replay.last.gps_ms
        entry = LogEntry(message, trigger, period_ms,
                         int(round(cmd.offset * 1000.0)) % period_ms, bool(cmd.hold), after_ms)
        if entry.trigger in (enums.Trigger.ONCE, enums.Trigger.ONCHANGED):
            def once():
                solution = self.twin.output.current_solution(now_s)
                if solution is not None:
                    self.twin.output.emit([message], solution)
            if entry.trigger == enums.Trigger.ONCHANGED:
                self.twin.logs[message] = entry
            return once
        self.twin.logs[message] = entry
        return None

    def _unlog(self, cmd: cmds.Unlog, now_s: float):
        self._check(2, self._known(cmd.port))
        if self._on_com1(cmd.port):
            if cmd.message not in self.twin.logs:
                raise Rejected(enums.ResponseId.LOG_DOES_NOT_EXIST)
            del self.twin.logs[enums.MessageId(cmd.message)]     # (one of the logs': a enums.MessageId)
        return None

    def _unlogall(self, cmd: cmds.Unlogall, now_s: float):
        self._check(2, self._known(cmd.port))
        self._check(3, cmd.held in (0, 1))
        here = self._cmd_port is self.twin.com1 and cmd.port == enums.Port.THISPORT_ALL
        if here or (cmd.port in OWN_UNLOGALL and cmd.port != enums.Port.THISPORT_ALL) or self._on_com1(cmd.port):
            self.twin.logs = {k: v for k, v in self.twin.logs.items() if v.hold and not cmd.held}
        return None

    def _com(self, cmd: cmds.Com, now_s: float):
        self._check(2, self._known(cmd.port) and cmd.port != enums.ComPort.ALL)
        if cmd.baud not in enums.COM_BAUDS:
            raise Rejected(enums.ResponseId.INVALID_BAUD_RATE)
        self._check(4, self._known(cmd.parity))
        self._check(5, cmd.databits in (7, 8), enums.ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(6, cmd.stopbits in (1, 2), enums.ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(7, self._known(cmd.handshake))
        self._check(8, cmd.echo in (0, 1))
        self._check(9, cmd.break_detection in (0, 1))
        port = self._com_port(cmd.port)
        if port is None:
            return None

        def switch():                           # the response still goes at the old rate
            port.baud = cmd.baud
        return switch

    def _interfacemode(self, cmd: cmds.InterfaceModeCommand, now_s: float):
        """INTERFACEMODE (§2.6.28): what a port takes from now on, after the response."""
        self._check(2, self._known(cmd.port) and cmd.port != enums.ComPort.ALL)
        self._check(3, self._known(cmd.rxtype))
        self._check(4, self._known(cmd.txtype))
        self._check(5, cmd.responses in (0, 1))
        port = self._com_port(cmd.port)
        if port is None:
            return None

        def switch():
            port.rxtype, port.txtype = enums.InterfaceMode(cmd.rxtype), enums.InterfaceMode(cmd.txtype)
            port.responses = bool(cmd.responses)
            port.line.clear()
            port.rtcm.clear()
        return switch

    def _dgpstimeout(self, cmd: cmds.DgpsTimeout, now_s: float):
        """DGPSTIMEOUT (§2.6.16): the oldest pseudorange corrections used, 2-1000 s."""
        self._check(2, 2 <= cmd.delay <= 1000, enums.ResponseId.PARAMETER_OUT_OF_RANGE)
        self.twin.dgps_timeout_s = float(cmd.delay)
        self.twin.corrections.apply_settings()
        return None

    def _source(self, cmd: cmds.PsrDiffSource | cmds.RtkSource, now_s: float):
        """PSRDIFFSOURCE / RTKSOURCE (§2.6.40, §2.6.47): whose corrections count. A new
        PSRDIFFSOURCE drops the corrections in use at once (§2.6.40 note 1)."""
        cmr_for_psrdiff = isinstance(cmd, cmds.PsrDiffSource) and cmd.type == enums.DgpsType.CMR
        self._check(2, self._known(cmd.type) and not cmr_for_psrdiff)
        self._check(3, not cmds.source_id_error(cmd.type, cmd.id))
        source = Source(int(cmd.type), cmd.id)
        if isinstance(cmd, cmds.PsrDiffSource):
            self.twin.psr_source = source
            if self.twin.corrections.rover is not None:
                self.twin.corrections.rover.machine.drop_corrections(self.twin._gps_ms(now_s) / 1000.0)
        else:
            self.twin.rtk_source = source
        self.twin.corrections.apply_settings()
        return None

    def _version(self, cmd: cmds.Log, now_s: float):
        """LOG VERSION ONCE (§3.4.94, a polled log): the receiver's one component."""
        self._check(4, (cmd.message_type >> 5) & 0x3 == enums.MessageFormat.BINARY)
        if cmd.trigger != enums.Trigger.ONCE:
            raise Rejected(enums.ResponseId.TRIGGER_NOT_VALID, enums.Trigger(cmd.trigger).name)
        port = self._log_port(cmd.port)
        if port is None:
            return None

        def output():
            header = self.twin.output.header(enums.MessageId.VERSION, self.twin._gps_ms(now_s),
                                             port_address=port.address)
            port.out += encode_frame(header, Version((self.twin.version,)).body())
        return output

    def _dynamics(self, cmd: cmds.DynamicsCommand, now_s: float):
        self._check(2, self._known(cmd.dynamics))
        self.twin.dynamics = enums.Dynamics(cmd.dynamics)     # (read as a enums.Dynamics already: the same member)
        return None

    def _sbascontrol(self, cmd: cmds.SbasControl, now_s: float):
        self._check(2, int(cmd.keyword) in (0, 1))
        self._check(3, self._known(cmd.system))
        self._check(4, cmd.prn == 0 or 120 <= cmd.prn <= 138, enums.ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(5, self._known(cmd.testmode))
        enable = int(cmd.keyword) == self.twin.sbas_enable_value        # as this firmware reads it
        self.twin.sbas = replace(cmd, keyword=enums.SbasKeyword.ENABLE if enable else enums.SbasKeyword.DISABLE)
        self.twin._apply_sbas()
        return None

    def _reset(self, cmd: cmds.Reset, now_s: float):
        self.twin._reset_at = now_s + cmd.delay
        return None

    def _saveconfig(self, cmd: cmds.SaveConfig, now_s: float):
        tw = self.twin
        ports = tuple((p.com, p.baud, p.rxtype, p.txtype, p.responses) for p in tw.ports.values())
        tw.saved = ReceiverConfig(tuple(tw.logs.values()), tw.baud, tw.dynamics, tw.sbas, ports,
                                  tw.dgps_timeout_s, tw.psr_source, tw.rtk_source)
        return None

    def _rxconfig(self, cmd: cmds.Log, now_s: float):
        """LOG RXCONFIG ONCE: after the response, one RXCONFIG log per setting."""
        fmt = (cmd.message_type >> 5) & 0x3
        self._check(4, fmt in (enums.MessageFormat.BINARY, enums.MessageFormat.ASCII))
        if cmd.trigger != enums.Trigger.ONCE:
            raise Rejected(enums.ResponseId.TRIGGER_NOT_VALID, enums.Trigger(cmd.trigger).name)
        if not self._on_com1(cmd.port):
            return None

        def output():
            self.twin._out += rxconfig_logs(self.twin, fmt, self.twin._gps_ms(now_s))
        return output

    #: each command's handler: (interpreter, command, now_s) -> what to do after the response, or None
    _HANDLERS: dict[type, Callable[..., Callable[[], None] | None]] = {
        cmds.Log: _log, cmds.Unlog: _unlog, cmds.Unlogall: _unlogall, cmds.Com: _com,
        cmds.DynamicsCommand: _dynamics, cmds.SbasControl: _sbascontrol, cmds.Reset: _reset,
        cmds.SaveConfig: _saveconfig, cmds.InterfaceModeCommand: _interfacemode, cmds.DgpsTimeout: _dgpstimeout,
        cmds.PsrDiffSource: _source, cmds.RtkSource: _source}
