"""The NovAtel OEM4-G2L's twin: binary commands in, binary responses and logs out.

It behaves as the receiver's binary interface on one port (COM1) does:
- every frame is checked as the receiver checks it: a bad CRC gets INVALID CHECKSUM (so the
  old library's SBASCONTROL, sent with length 0, is refused the way the car refused it),
  an unknown ID INVALID MESSAGE ID, a body of the wrong size MESSAGE MISSING FIELD, a
  field out of its table INVALID MESSAGE. FIELD = n (n counts the header as field 1);
- LOG / UNLOG / UNLOGALL / COM / DYNAMICS / SBASCONTROL / RESET / SAVECONFIG take effect
  as the manual says; logs come out at their trigger: ONTIME on GPS-time multiples of the
  period (at most 20 Hz), ONNEW/ONCHANGED at each new solution, ONNEXT and ONCE once;
- logs BESTXYZ, BESTPOS and BESTVEL, from the simulated car's truth (TruthSolver) or from
  the real drive of 2016 at its recorded pace (``replay``), where every requested log
  comes out on every recorded epoch (or on those matching a slower ONTIME period);
- the polled log RXCONFIG (ONCE, binary or ASCII, §3.4.84): one log per setting it holds
  (COM, DYNAMICS, SBASCONTROL, each LOG), each embedding that command with its CRC
  inverted, counting down to 0; in ASCII the enumerations are labels, so SBASCONTROL reads
  ENABLE or DISABLE as the receiver understood the command.
SBASCONTROL's binary keyword: the OEM4 2.310 manual's table reads 0 as ENABLE, later
firmware reads 1; ``sbas_enable_value`` says which firmware this twin runs.
Commands are binary only: ASCII input is ignored, as is anything that is not a frame.

A TCP connection cannot carry a serial break, and the driver sends one on every open, so
a new connection does what the break does (COM §2.6.10): this port's non-held logs stop,
its rate returns to 9600, its buffers are cleared (docs/sensors.md#the-twins-timing). Section
numbers are OEM4 vol. 2's (docs/README.md#sources).
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from viena.common.twin.serial_port import ByteTwin
from viena.services.gnss.driver.gpstime import gps_to_utc_ns
from viena.services.gnss.driver.novatel.ascii import ascii_line, rxconfig_text
from viena.services.gnss.driver.novatel.commands import (
    COMMANDS,
    BodyError,
    Com,
    Command,
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
from viena.services.gnss.driver.novatel.enums import (
    COM_BAUDS,
    RESPONSE_TEXT,
    ComPort,
    Dynamics,
    MessageFormat,
    MessageId,
    Port,
    PositionType,
    ResponseId,
    SbasKeyword,
    SbasSystem,
    SbasTestMode,
    TimeStatus,
    Trigger,
)
from viena.services.gnss.driver.novatel.framing import (
    BINARY_MESSAGE_TYPE,
    CRC_LENGTH,
    HEADER_LENGTH,
    MAX_BODY_LENGTH,
    SYNC,
    Header,
    crc32,
    encode_frame,
    frame_of,
    pack_header,
    unpack_header,
)
from viena.services.gnss.driver.novatel.logs import BestPos, BestVel, BestXyz

from .clock import WEEK_MS, GpsClock
from .errors import CommonErrors, GnssErrorModel, SkyModel
from .replay import EPOCH_MS, DriveReplay, RecordedEpoch
from .solution import Solution, TruthSolver

#: The OEM4-G2L computes and logs at up to 20 Hz.
MIN_PERIOD_MS = 50
MAX_LOGS = 30                   # "The OEM4 family of receivers can handle 30 logs at a time"
FACTORY_BAUD = 9600
SW_VERSION = 1522
IDLE_TIME = 160                 # 80 % idle, in the header's half-percent units
OWN_COM = ComPort.COM1
OWN_PORT = Port.COM1
OWN_UNLOGALL = (Port.THISPORT_ALL, Port.ALL_PORTS, Port.COM1_ALL)
ACTIVE_TRIGGERS = (Trigger.ONNEW, Trigger.ONCHANGED, Trigger.ONTIME, Trigger.ONNEXT)


class Rejected(Exception):
    """A command the receiver refuses, with its response ID and text argument."""

    def __init__(self, response_id: ResponseId, arg=None):
        self.response_id = ResponseId(response_id)
        self.text = RESPONSE_TEXT.get(self.response_id, self.response_id.name).format(arg)


@dataclass
class LogEntry:
    message: MessageId
    trigger: Trigger
    period_ms: int
    offset_ms: int
    hold: bool
    after_ms: int = -1              # requested at this GPS time: only later epochs come out

    def fires_at(self, gps_ms: int, epoch_ms: int) -> bool:
        """Whether a solution epoch at ``gps_ms`` is output by this log."""
        if gps_ms <= self.after_ms:
            return False
        if self.trigger == Trigger.ONTIME and self.period_ms > epoch_ms:
            return gps_ms % self.period_ms == self.offset_ms
        return self.trigger in ACTIVE_TRIGGERS


@dataclass
class ReceiverConfig:
    """What SAVECONFIG stores and RESET restores. SBAS as the receiver understood it: the
    keyword is its meaning (the OEM4 table's name), whatever number carried it."""

    logs: tuple = ()
    baud: int = FACTORY_BAUD
    dynamics: Dynamics = Dynamics.AIR
    sbas: SbasControl = SbasControl(SbasKeyword.DISABLE, SbasSystem.AUTO)   # "DISABLE AUTO 0 NONE"


def bestxyz_of(s: Solution) -> BestXyz:
    return BestXyz(*_bestxyz_fields(s))


def _bestxyz_fields(s: Solution) -> tuple:
    return (s.pos_status, s.pos_type, s.ecef_m, s.ecef_sigma_m, s.vel_status, s.vel_type, s.vel_ecef_mps,
            s.vel_sigma_mps, "", s.vel_latency_s, s.diff_age_s, s.sol_age_s, s.sats_tracked, s.sats_used)


def bestpos_of(s: Solution) -> BestPos:
    lat, lon, h = s.geodetic()
    e, n, u = s.enu_sigma()
    return BestPos(s.pos_status, s.pos_type, lat, lon, h - s.undulation_m, s.undulation_m,
                   lat_sigma_m=n, lon_sigma_m=e, height_sigma_m=u, diff_age_s=s.diff_age_s,
                   sol_age_s=s.sol_age_s, sats_tracked=s.sats_tracked, sats_used=s.sats_used)


def bestvel_of(s: Solution) -> BestVel:
    e, n, u = s.enu_velocity()
    track = math.degrees(math.atan2(e, n)) % 360.0
    return BestVel(s.vel_status, s.vel_type, s.vel_latency_s, s.diff_age_s, math.hypot(e, n),
                   track, u)


LOG_MAKERS: dict[int, Callable[[Solution], object]] = {
    MessageId.BESTXYZ: bestxyz_of, MessageId.BESTPOS: bestpos_of, MessageId.BESTVEL: bestvel_of,
}
#: each log's body, as LOG_MAKERS[id](solution).body(); BESTXYZ, every epoch, without making its log
LOG_BODIES: dict[int, Callable[[Solution], bytes]] = {
    MessageId.BESTXYZ: lambda s: BestXyz.pack(*_bestxyz_fields(s)),
    MessageId.BESTPOS: lambda s: bestpos_of(s).body(), MessageId.BESTVEL: lambda s: bestvel_of(s).body(),
}


class NovatelTwin(ByteTwin):
    """An OEM4 receiver on one serial port, solving from truth or replaying a drive.

    From the simulated car::

        NovatelTwin(car.truth, lever_arm_m=(0.5, 1.2, 1.5), seed=3)

    Two receivers on one car share one sky (satellite clock, orbit and atmosphere errors)::

        sky = CommonErrors(np.random.default_rng(1))
        NovatelTwin(car.truth, (-0.5, 1.0, 1.5), seed=3, common_errors=sky)
        NovatelTwin(car.truth, (0.5, 1.0, 1.5), seed=4, common_errors=sky)

    Replaying the 2016 drive (``truth`` is then not needed)::

        NovatelTwin(replay=load_drive(), replay_loop=True)
    """

    def __init__(self, truth: Callable | None = None, lever_arm_m=(0.0, 0.0, 0.0), *,
                 seed: int = 0, cep_m: float = 1.8, sbas_cep_m: float | None = None,
                 outage_interval_s: float = 64.0, outages=(), undulation_m: float = 55.0,
                 output_delay_s: float = 0.02, boot_s: float = 1.0,
                 reset_cold_start_s: float = 5.0, sbas_enable_value: int = SbasKeyword.ENABLE,
                 common_errors: CommonErrors | None = None,
                 replay: list[RecordedEpoch] | None = None, replay_speed: float = 1.0,
                 replay_loop: bool = False, replay_retime: bool = True):
        if truth is None and replay is None:
            raise ValueError("a NovatelTwin needs truth or a recording to replay")
        rng = np.random.default_rng(seed)
        self.cep_m = cep_m
        self.sbas_cep_m = cep_m if sbas_cep_m is None else sbas_cep_m
        self.sbas_enable_value = sbas_enable_value
        self.solver = None if truth is None else TruthSolver(
            truth, lever_arm_m, errors=GnssErrorModel(rng, cep_m=cep_m, common=common_errors),
            sky=SkyModel(rng, outage_interval_s=outage_interval_s, outages=outages),
            undulation_m=undulation_m)
        self.output_delay_s = output_delay_s
        self.boot_s = boot_s
        self.reset_cold_start_s = reset_cold_start_s
        self.replay = (None if replay is None
                       else DriveReplay(list(replay), replay_speed, replay_loop, replay_retime,
                                        undulation_m))
        # receiver state
        self.logs: dict[MessageId, LogEntry] = {}
        self.saved: ReceiverConfig | None = None
        self.baud = FACTORY_BAUD
        self.dynamics = Dynamics.AIR
        self.sbas = ReceiverConfig.sbas
        self.history: deque = deque(maxlen=100)     # (command, response text), newest last
        self.checksum_errors = 0
        # line and clock
        self._rx = bytearray()
        self._out = bytearray()
        self.clock = GpsClock()
        self._next_epoch_ms: int | None = None
        self._last_solution: Solution | None = None
        self._boot_until = -math.inf
        self._reset_at: float | None = None
        self._boot_gps_ms = 0

    # -- ByteTwin --------------------------------------------------------------------
    def on_connect(self, now_s: float) -> None:
        self.clock.ensure(now_s)
        self._rx.clear()
        self._out.clear()
        self.logs = {k: v for k, v in self.logs.items() if v.hold}
        self.baud = FACTORY_BAUD

    def feed(self, data: bytes, now_s: float) -> None:
        self.clock.ensure(now_s)
        if now_s < self._boot_until:
            return                              # deaf while it boots
        self._rx += data
        self._parse_commands(now_s)

    def poll(self, now_s: float) -> bytes:
        self.clock.ensure(now_s)
        if self._reset_at is not None and now_s >= self._reset_at:
            said = bytes(self._out)             # the RESET's own response still goes out
            self._reboot(now_s)
            return said
        if now_s < self._boot_until:
            return b""
        if self.replay is not None:
            self._replay_due(now_s)
        else:
            self._solve_due(now_s)
        out = bytes(self._out)
        self._out.clear()
        return out

    def next_due(self, now_s: float) -> float:
        if self._out:
            return now_s
        due = now_s + 0.1
        if self._reset_at is not None:
            due = min(due, self._reset_at)
        if now_s < self._boot_until:
            return min(due, self._boot_until)
        if self.replay is not None:
            replay_due = self.replay.next_time()
            if replay_due is not None:
                due = min(due, replay_due)
        elif self.logs and self._next_epoch_ms is not None:
            due = min(due, self.clock.now_of(self._next_epoch_ms) + self.output_delay_s)
        return max(due, now_s)

    # -- time ------------------------------------------------------------------------
    def _gps_ms(self, now_s: float) -> int:
        return self.clock.gps_ms(now_s)

    def _header(self, message_id: int, gps_ms: int, *, message_type=BINARY_MESSAGE_TYPE,
                sequence: int = 0, time_status: TimeStatus | None = None) -> Header:
        time_status, week, ms = self._time_tag(gps_ms, time_status)
        return Header(message_id, message_type=message_type, port_address=OWN_PORT,
                      sequence=sequence, idle_time=IDLE_TIME, time_status=time_status,
                      week=week, milliseconds=ms, sw_version=SW_VERSION)

    def _time_tag(self, gps_ms: int, time_status: TimeStatus | None = None) -> tuple[TimeStatus, int, int]:
        """A header's time status, week and milliseconds for an epoch."""
        if time_status is None:
            last = self._last_solution
            time_status = (TimeStatus.FREEWHEELING if last is not None and not last.has_fix
                           else TimeStatus.FINESTEERING)
        if self.solver is not None and gps_ms < self.solver.no_fix_until_ms:
            # cold start: the receiver does not know the time yet and counts from week 0
            time_status = TimeStatus.UNKNOWN
            gps_ms = max(0, gps_ms - self._boot_gps_ms)
        week, ms = divmod(gps_ms, WEEK_MS)
        return time_status, week, ms

    # -- logs ------------------------------------------------------------------------
    def _emit(self, messages, solution: Solution) -> None:
        # encode_frame(self._header(message, gps_ms), body) without making the Header
        time_status, week, ms = self._time_tag(solution.gps_ms)
        for message in messages:
            body = LOG_BODIES[message](solution)
            header = pack_header(message, BINARY_MESSAGE_TYPE, OWN_PORT, len(body), 0, IDLE_TIME, time_status,
                                 week, ms, sw_version=SW_VERSION)
            self._out += frame_of(header, body)

    def _solve(self, gps_ms: int) -> Solution:
        last = self._last_solution
        if last is not None and last.gps_ms == gps_ms:
            return last
        solution = self.solver.solve(gps_ms, gps_to_utc_ns(*divmod(gps_ms, WEEK_MS)))
        self._last_solution = solution
        return solution

    def _solve_due(self, now_s: float) -> None:
        """Output the logs of every solution epoch that is due by now."""
        if not self.logs:
            self._next_epoch_ms = None
            return
        last_due = self._gps_ms(now_s - self.output_delay_s)
        if self._next_epoch_ms is None or self._next_epoch_ms < last_due - 1000:
            # start (or, after a stall of over a second, resume) at the latest epoch
            self._next_epoch_ms = last_due // MIN_PERIOD_MS * MIN_PERIOD_MS
        while self._next_epoch_ms <= last_due and self.logs:
            gps_ms = self._next_epoch_ms
            self._next_epoch_ms += MIN_PERIOD_MS
            due = [m for m, e in self.logs.items() if e.fires_at(gps_ms, MIN_PERIOD_MS)]
            if due:
                self._emit(due, self._solve(gps_ms))
                self._drop_onnext(due)

    def _drop_onnext(self, messages) -> None:
        for m in messages:
            if self.logs[m].trigger == Trigger.ONNEXT:
                del self.logs[m]

    def _current_solution(self, now_s: float) -> Solution | None:
        """The latest solution (for ONCE and the first ONCHANGED output)."""
        if self.replay is not None:
            return self.replay.last
        gps_ms = self._gps_ms(now_s - self.output_delay_s) // MIN_PERIOD_MS * MIN_PERIOD_MS
        if self._last_solution is not None and self._last_solution.gps_ms > gps_ms:
            return self._last_solution
        return self._solve(gps_ms)

    # -- replay ----------------------------------------------------------------------
    def _begin_replay(self, now_s: float) -> None:
        self.replay.begin(now_s, self._gps_ms(now_s))
        if not self.replay.retime:              # the receiver lives in the recording's time
            self.clock.anchor(now_s, self.replay.host_gps_ms(0))

    def _replay_due(self, now_s: float) -> None:
        for solution in self.replay.due(now_s):
            self._last_solution = solution
            due = [m for m, e in self.logs.items() if e.fires_at(solution.gps_ms, EPOCH_MS)]
            if due:
                self._emit(due, solution)
                self._drop_onnext(due)

    # -- commands --------------------------------------------------------------------
    def _parse_commands(self, now_s: float) -> None:
        """Take complete frames off the input as the receiver does: a frame is as long as
        its header says, and its CRC decides whether it is executed or refused."""
        buf = self._rx
        while True:
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
                self.checksum_errors += 1
                self._respond(header, now_s, Rejected(ResponseId.INVALID_CHECKSUM))
                continue
            if header.is_response or header.message_format != 0:
                continue                        # only binary commands are understood
            self._execute(header, frame[header.header_length:-CRC_LENGTH], now_s)

    def _respond(self, header: Header, now_s: float, result: Rejected | None) -> None:
        response = (Response(ResponseId.OK, "OK") if result is None
                    else Response(result.response_id, result.text))
        self.history.append((MessageId(header.message_id).name, response.text))
        out = self._header(header.message_id, self._gps_ms(now_s),
                           message_type=header.message_type, sequence=header.sequence)
        self._out += response.frame(out)

    def _execute(self, header: Header, body: bytes, now_s: float) -> None:
        cls = COMMANDS.get(header.message_id)
        after = None
        try:
            if cls is None:
                raise Rejected(ResponseId.INVALID_MESSAGE_ID)
            try:
                command = cls.from_body(body)
            except BodyError:
                raise Rejected(ResponseId.MESSAGE_MISSING_FIELD) from None
            after = self._HANDLERS[cls](self, command, now_s)
        except Rejected as rejected:
            self._respond(header, now_s, rejected)
            return
        self._respond(header, now_s, None)
        if after is not None:
            after()

    @staticmethod
    def _check(field_no: int, ok: bool, response=ResponseId.INVALID_MESSAGE_FIELD) -> None:
        if not ok:
            raise Rejected(response, field_no)

    def _known(self, value) -> bool:
        return not value.name.startswith("UNKNOWN_")

    def _log(self, cmd: Log, now_s: float):
        self._check(2, self._known(cmd.port))
        if cmd.message == MessageId.RXCONFIG:
            return self._rxconfig(cmd, now_s)
        if cmd.message not in LOG_MAKERS:
            raise Rejected(ResponseId.LOG_DOES_NOT_EXIST)
        self._check(4, (cmd.message_type >> 5) & 0x3 == 0)       # the twin speaks binary
        self._check(6, self._known(cmd.trigger))
        self._check(7, math.isfinite(cmd.period) and cmd.period >= 0.0,
                    ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(9, cmd.hold in (0, 1))
        period_ms = max(MIN_PERIOD_MS, int(round(cmd.period * 1000.0)))
        if cmd.trigger == Trigger.ONTIME:
            self._check(7, cmd.period > 0.0, ResponseId.PARAMETER_OUT_OF_RANGE)
            if not (math.isfinite(cmd.offset) and 0.0 <= cmd.offset < max(cmd.period, 0.05)):
                raise Rejected(ResponseId.INVALID_OFFSET)
        if cmd.port not in (Port.THISPORT, OWN_PORT):
            return None                         # logged on another port: not ours to send
        message = MessageId(cmd.message)
        if message not in self.logs and len(self.logs) >= MAX_LOGS:
            raise Rejected(ResponseId.NOT_ENOUGH_RESOURCES)
        trigger = Trigger(cmd.trigger)
        if self.replay is None:
            after_ms = self._gps_ms(now_s)
        else:
            if not self.replay.started and trigger not in (Trigger.ONCE, Trigger.ONMARK):
                self._begin_replay(now_s)
            after_ms = -1 if self.replay.last is None else self.replay.last.gps_ms
        entry = LogEntry(message, trigger, period_ms,
                         int(round(cmd.offset * 1000.0)) % period_ms, bool(cmd.hold), after_ms)
        if entry.trigger in (Trigger.ONCE, Trigger.ONCHANGED):
            def once():
                solution = self._current_solution(now_s)
                if solution is not None:
                    self._emit([message], solution)
            if entry.trigger == Trigger.ONCHANGED:
                self.logs[message] = entry
            return once
        self.logs[message] = entry
        return None

    def _unlog(self, cmd: Unlog, now_s: float):
        self._check(2, self._known(cmd.port))
        if cmd.port in (Port.THISPORT, OWN_PORT):
            if cmd.message not in self.logs:
                raise Rejected(ResponseId.LOG_DOES_NOT_EXIST)
            del self.logs[cmd.message]
        return None

    def _unlogall(self, cmd: Unlogall, now_s: float):
        self._check(2, self._known(cmd.port))
        self._check(3, cmd.held in (0, 1))
        if cmd.port in OWN_UNLOGALL or cmd.port in (Port.THISPORT, OWN_PORT):
            self.logs = {k: v for k, v in self.logs.items() if v.hold and not cmd.held}
        return None

    def _com(self, cmd: Com, now_s: float):
        self._check(2, self._known(cmd.port) and cmd.port != ComPort.ALL)
        if cmd.baud not in COM_BAUDS:
            raise Rejected(ResponseId.INVALID_BAUD_RATE)
        self._check(4, self._known(cmd.parity))
        self._check(5, cmd.databits in (7, 8), ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(6, cmd.stopbits in (1, 2), ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(7, self._known(cmd.handshake))
        self._check(8, cmd.echo in (0, 1))
        self._check(9, cmd.break_detection in (0, 1))
        if cmd.port not in (ComPort.THISPORT, OWN_COM):
            return None

        def switch():                           # the response still goes at the old rate
            self.baud = cmd.baud
        return switch

    def _dynamics(self, cmd: DynamicsCommand, now_s: float):
        self._check(2, self._known(cmd.dynamics))
        self.dynamics = cmd.dynamics
        return None

    def _sbascontrol(self, cmd: SbasControl, now_s: float):
        self._check(2, int(cmd.keyword) in (0, 1))
        self._check(3, self._known(cmd.system))
        self._check(4, cmd.prn == 0 or 120 <= cmd.prn <= 138, ResponseId.PARAMETER_OUT_OF_RANGE)
        self._check(5, self._known(cmd.testmode))
        enable = int(cmd.keyword) == self.sbas_enable_value        # as this firmware reads it
        self.sbas = replace(cmd, keyword=SbasKeyword.ENABLE if enable else SbasKeyword.DISABLE)
        self._apply_sbas()
        return None

    def _apply_sbas(self) -> None:
        if self.solver is None:
            return
        using = self.sbas.keyword == SbasKeyword.ENABLE and self.sbas.system != SbasSystem.NONE
        self.solver.pos_type = PositionType.WAAS if using else PositionType.SINGLE
        self.solver.errors.set_cep(self.sbas_cep_m if using else self.cep_m)

    def _reset(self, cmd: Reset, now_s: float):
        self._reset_at = now_s + cmd.delay
        return None

    def _saveconfig(self, cmd: SaveConfig, now_s: float):
        self.saved = ReceiverConfig(tuple(self.logs.values()), self.baud, self.dynamics, self.sbas)
        return None

    # -- RXCONFIG ----------------------------------------------------------------------
    def _rxconfig(self, cmd: Log, now_s: float):
        """LOG RXCONFIG ONCE: after the response, one RXCONFIG log per setting."""
        fmt = (cmd.message_type >> 5) & 0x3
        self._check(4, fmt in (MessageFormat.BINARY, MessageFormat.ASCII))
        if cmd.trigger != Trigger.ONCE:
            raise Rejected(ResponseId.TRIGGER_NOT_VALID, Trigger(cmd.trigger).name)
        if cmd.port not in (Port.THISPORT, OWN_PORT):
            return None

        def output():
            settings = self._settings()
            gps_ms = self._gps_ms(now_s)
            for k, (command, text) in enumerate(settings):
                sequence = len(settings) - 1 - k
                if fmt == MessageFormat.ASCII:
                    self._out += ascii_line(rxconfig_text(command.name, text, sequence,
                                                          **self._ascii_header(gps_ms)))
                else:
                    self._out += self._rxconfig_binary(command, sequence, gps_ms)
        return output

    def _settings(self) -> list[tuple[Command, str]]:
        """What the receiver holds, as commands and as RXCONFIGA writes them (by label)."""
        sb = self.sbas
        keyword = sbas_keyword_value(SbasKeyword(sb.keyword), self.sbas_enable_value)
        out = [(Com(ComPort.COM1, self.baud), f"COM1,{self.baud},N,8,1,N,OFF,ON"),
               (DynamicsCommand(self.dynamics), Dynamics(self.dynamics).name),
               (replace(sb, keyword=keyword),
                f"{SbasKeyword(sb.keyword).name},{SbasSystem(sb.system).name},{sb.prn},"
                f"{SbasTestMode(sb.testmode).name}")]
        for e in self.logs.values():
            out.append((Log(OWN_PORT, e.message, 0, 0, e.trigger, e.period_ms / 1000.0,
                            e.offset_ms / 1000.0, int(e.hold)),
                        f"COM1,{MessageId(e.message).name}B,{Trigger(e.trigger).name},"
                        f"{e.period_ms / 1000.0:.6f},{e.offset_ms / 1000.0:.6f},"
                        f"{'HOLD' if e.hold else 'NOHOLD'}"))
        return out

    def _ascii_header(self, gps_ms: int) -> dict:
        h = self._header(MessageId.RXCONFIG, gps_ms)
        return dict(port="COM1", idle_percent=h.idle_percent,
                    time_status=TimeStatus(h.time_status).name, week=h.week,
                    seconds=h.milliseconds / 1000.0, receiver_status=h.receiver_status,
                    sw_version=h.sw_version)

    def _rxconfig_binary(self, command: Command, sequence: int, gps_ms: int) -> bytes:
        """Binary RXCONFIG: the embedded command's header and body, its CRC inverted."""
        inner = command.frame(port_address=OWN_PORT, sequence=sequence)
        crc = int.from_bytes(inner[-CRC_LENGTH:], "little") ^ 0xFFFFFFFF
        body = inner[:-CRC_LENGTH] + crc.to_bytes(CRC_LENGTH, "little")
        return encode_frame(self._header(MessageId.RXCONFIG, gps_ms, sequence=sequence), body)

    _HANDLERS = {Log: _log, Unlog: _unlog, Unlogall: _unlogall, Com: _com,
                 DynamicsCommand: _dynamics, SbasControl: _sbascontrol, Reset: _reset,
                 SaveConfig: _saveconfig}

    def _reboot(self, now_s: float) -> None:
        """RESET: silent while booting, then the saved configuration (or the factory's),
        and no fix until the receiver has acquired satellites again."""
        self._reset_at = None
        self._boot_until = now_s + self.boot_s
        config = self.saved or ReceiverConfig()
        self.logs = {e.message: replace(e) for e in config.logs}
        self.baud, self.dynamics, self.sbas = config.baud, config.dynamics, config.sbas
        self._apply_sbas()
        self._rx.clear()
        self._out.clear()
        self._next_epoch_ms = None
        self._last_solution = None
        if self.solver is not None:
            self._boot_gps_ms = self._gps_ms(self._boot_until)
            self.solver.cold_start(self._boot_gps_ms + int(self.reset_cold_start_s * 1000))
