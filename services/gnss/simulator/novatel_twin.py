"""The NovAtel OEM4-G2L's twin: binary commands in, binary responses and logs out.

It behaves as the receiver's binary interface on its COM1 does (and its COM2, see below):
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
- the polled log VERSION (ONCE, binary, §3.4.94): one GPSCARD component, its model and
  firmware the constructor's (``model``, ``firmware``);
- corrections: INTERFACEMODE (§2.6.28) sets what a port takes; a port whose receive type is
  RTCMV3 takes no more commands and reads RTCM 3 at its baud (ports.py: bytes beyond what
  the line carries are lost, ``overruns``; rtcm_in.py: 1001-1006 used, the rest skipped and
  counted), and the solutions move through PSRDIFF, float and fixed (rtk.py, differential.py,
  rover.py; DGPSTIMEOUT, PSRDIFFSOURCE and RTKSOURCE as §2.6.16, 2.6.40, 2.6.47 say);
  BESTXYZ/BESTPOS carry the type, the differential age and the base's ID. COM2 is
  ``port("COM2")``, a ByteTwin of its own on the same receiver: it takes commands (answered
  on COM2) until COM1 or itself sets it to RTCMV3; logs come out on COM1 only. Until the
  first corrections are read, its fixes are byte for byte what they were before.
SBASCONTROL's binary keyword: the OEM4 2.310 manual's table reads 0 as ENABLE, later
firmware reads 1; ``sbas_enable_value`` says which firmware this twin runs.
Commands are binary only: ASCII input is ignored, as is anything that is not a frame.

A TCP connection cannot carry a serial break, and the driver sends one on every open, so
a new connection to COM1 does what the break does (COM §2.6.10): this port's non-held logs
stop, its rate returns to 9600, its buffers are cleared, its interface mode is NOVATEL
NOVATEL again (docs/sensors.md#the-twins-timing); one to COM2 changes nothing (no break goes
down a corrections cable). Section numbers are OEM4 vol. 2's (docs/README.md#sources).
"""
from __future__ import annotations

import math
import threading
from collections import Counter, deque
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
    DgpsTimeout,
    DynamicsCommand,
    InterfaceModeCommand,
    Log,
    PsrDiffSource,
    Reset,
    Response,
    RtkSource,
    SaveConfig,
    SbasControl,
    Unlog,
    Unlogall,
    sbas_keyword_value,
    source_id_error,
)
from viena.services.gnss.driver.novatel.enums import (
    COM_BAUDS,
    RESPONSE_TEXT,
    ComponentType,
    ComPort,
    DgpsType,
    Dynamics,
    InterfaceMode,
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
from viena.services.gnss.driver.novatel.logs import BestPos, BestVel, BestXyz, Component, Version

from .clock import WEEK_MS, GpsClock
from .errors import CommonErrors, GnssErrorModel, SkyModel
from .ports import FACTORY_BAUD, LINE_BUFFER_BYTES, PortTwin, ReceiverPort
from .replay import EPOCH_MS, DriveReplay, RecordedEpoch
from .rover import Rover
from .rtcm_in import BasePosition
from .rtk import DEFAULT_FIGURES, FACTORY_DGPS_TIMEOUT_S, RtkFigures, Source, engine_of_model
from .solution import Solution, TruthSolver

#: The OEM4-G2L computes and logs at up to 20 Hz.
MIN_PERIOD_MS = 50
MAX_LOGS = 30                   # "The OEM4 family of receivers can handle 30 logs at a time"
SW_VERSION = 1522
#: The receiver VERSION describes by default: vol. 2 §3.4.94's example, an RT-2 OEM4-G2
#: ("RT2WA", "OEM4g2-2.00-X2T"), on the manual's firmware.
DEFAULT_MODEL = "RT2WA"
DEFAULT_FIRMWARE = "2.310"
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
    ports: tuple = ()               # (com, baud, rxtype, txtype, responses) of the other ports, and COM1's modes
    dgps_timeout_s: float = FACTORY_DGPS_TIMEOUT_S
    psr_source: Source = Source()
    rtk_source: Source = Source()


def bestxyz_of(s: Solution) -> BestXyz:
    return BestXyz(*_bestxyz_fields(s))


def _bestxyz_fields(s: Solution) -> tuple:
    return (s.pos_status, s.pos_type, s.ecef_m, s.ecef_sigma_m, s.vel_status, s.vel_type, s.vel_ecef_mps,
            s.vel_sigma_mps, s.station_id, s.vel_latency_s, s.diff_age_s, s.sol_age_s, s.sats_tracked, s.sats_used,
            s.sats_l1_rtk, s.sats_l2_rtk)


def bestpos_of(s: Solution) -> BestPos:
    lat, lon, h = s.geodetic()
    e, n, u = s.enu_sigma()
    return BestPos(s.pos_status, s.pos_type, lat, lon, h - s.undulation_m, s.undulation_m,
                   lat_sigma_m=n, lon_sigma_m=e, height_sigma_m=u, station_id=s.station_id,
                   diff_age_s=s.diff_age_s, sol_age_s=s.sol_age_s, sats_tracked=s.sats_tracked,
                   sats_used=s.sats_used, sats_l1_rtk=s.sats_l1_rtk, sats_l2_rtk=s.sats_l2_rtk)


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
    """An OEM4 receiver, solving from truth or replaying a drive; this object is its COM1.

    From the simulated car::

        NovatelTwin(car.truth, lever_arm_m=(0.5, 1.2, 1.5), seed=3)

    Two receivers on one car share one sky (satellite clock, orbit and atmosphere errors)::

        sky = CommonErrors(np.random.default_rng(1))
        NovatelTwin(car.truth, (-0.5, 1.0, 1.5), seed=3, common_errors=sky)
        NovatelTwin(car.truth, (0.5, 1.0, 1.5), seed=4, common_errors=sky)

    Replaying the 2016 drive (``truth`` is then not needed)::

        NovatelTwin(replay=load_drive(), replay_loop=True)

    Corrections: a port whose INTERFACEMODE receive type is RTCMV3 reads RTCM 3 at its baud
    (ports.py, rtcm_in.py) and the solution moves through the differential types (rtk.py,
    differential.py); ``port("COM2")`` is the second port as a ByteTwin of its own, for
    corrections beside COM1's commands and logs. ``model`` and ``firmware`` are what VERSION
    says, and the model decides what the receiver computes (rtk.engine_of_model).
    """

    def __init__(self, truth: Callable | None = None, lever_arm_m=(0.0, 0.0, 0.0), *,
                 seed: int = 0, cep_m: float = 1.8, sbas_cep_m: float | None = None,
                 outage_interval_s: float = 64.0, outages=(), undulation_m: float = 55.0,
                 output_delay_s: float = 0.02, boot_s: float = 1.0,
                 reset_cold_start_s: float = 5.0, sbas_enable_value: int = SbasKeyword.ENABLE,
                 common_errors: CommonErrors | None = None,
                 replay: list[RecordedEpoch] | None = None, replay_speed: float = 1.0,
                 replay_loop: bool = False, replay_retime: bool = True,
                 model: str = DEFAULT_MODEL, firmware: str = DEFAULT_FIRMWARE,
                 line_buffer_bytes: int = LINE_BUFFER_BYTES, rtk_figures: RtkFigures = DEFAULT_FIGURES):
        if truth is None and replay is None:
            raise ValueError("a NovatelTwin needs truth or a recording to replay")
        rng = np.random.default_rng(seed)
        self.seed = seed
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
        self.version = Component(ComponentType.GPSCARD, model=model, psn="SVA03130089",
                                 hw_version="OEM4g2-2.00-X2T", sw_version=firmware, boot_version="2.000")
        self.engine = engine_of_model(model)
        self.rtk_figures = rtk_figures
        # receiver state
        self.logs: dict[MessageId, LogEntry] = {}
        self.saved: ReceiverConfig | None = None
        self.dynamics = Dynamics.AIR
        self.sbas = ReceiverConfig.sbas
        self.dgps_timeout_s = FACTORY_DGPS_TIMEOUT_S
        self.psr_source = self.rtk_source = Source()
        self.history: deque = deque(maxlen=100)     # (command, response text), newest last
        self.checksum_errors = 0
        self.unread_bytes = 0                       # bytes on a port in a mode this twin does not read
        self._rover: Rover | None = None            # made when the first corrections are read
        # ports, line and clock
        self.com1 = ReceiverPort(ComPort.COM1, Port.COM1)
        self.com2 = ReceiverPort(ComPort.COM2, Port.COM2)
        self.ports: dict[int, ReceiverPort] = {ComPort.COM1: self.com1, ComPort.COM2: self.com2}   # by port field
        for p in self.ports.values():
            p.line.buffer_bytes = line_buffer_bytes
        self._rx = self.com1.rx
        self._out = self.com1.out
        self._cmd_port = self.com1                  # the port the command in hand came on
        self._lock = threading.Lock()               # COM1 and COM2 may be served from two threads
        self.clock = GpsClock()
        self._next_epoch_ms: int | None = None
        self._last_solution: Solution | None = None
        self._boot_until = -math.inf
        self._reset_at: float | None = None
        self._boot_gps_ms = 0

    @property
    def baud(self) -> int:
        """COM1's rate."""
        return self.com1.baud

    @baud.setter
    def baud(self, value: int) -> None:
        self.com1.baud = value

    def port(self, name: str) -> ByteTwin:
        """A port of this receiver as a ByteTwin: COM1 is the twin itself."""
        com = ComPort[name.upper()]
        if com == ComPort.COM1:
            return self
        if com not in self.ports:
            raise ValueError(f"the twin has no port {name!r} (it has {', '.join(p.name for p in self.ports.values())})")
        return PortTwin(self, com)

    # -- what corrections did -----------------------------------------------------------
    @property
    def rover(self) -> Rover | None:
        """The receiver's differential side, once it has read corrections."""
        return self._rover

    @property
    def correction_ages_s(self) -> list[float]:
        """Every observables message's age when the receiver read it: its GPS time at the
        read minus the base's epoch (s), oldest first."""
        return [] if self._rover is None else list(self._rover.correction_ages_s)

    @property
    def overruns(self) -> int:
        """Bytes lost on the ports: more than their lines carried."""
        return sum(p.line.overruns for p in self.ports.values())

    @property
    def rtcm_ignored(self) -> Counter:
        """RTCM 3 frames read and not used (not 1001-1006), by message number."""
        return sum((p.rtcm.ignored for p in self.ports.values()), Counter())

    @property
    def rtcm_malformed(self) -> Counter:
        """RTCM 3 frames whose CRC checked but whose message did not parse, by message number."""
        return sum((p.rtcm.malformed for p in self.ports.values()), Counter())

    @property
    def rtcm_crc_errors(self) -> int:
        return sum(p.rtcm.crc_errors for p in self.ports.values())

    def corrections_health(self) -> dict:
        """What corrections came to, for the sim's health ({} while none came): the ages at
        the read (p50/p95/max, s), what the ports lost or skipped, the latest solution."""
        rover = self._rover
        lost = (self.overruns + self.rtcm_crc_errors + sum(self.rtcm_ignored.values())
                + sum(self.rtcm_malformed.values()) + self.unread_bytes)
        if rover is None and not lost:
            return {}
        out: dict = {"overruns": self.overruns, "rtcm_crc_errors": self.rtcm_crc_errors,
                     "rtcm_ignored": sum(self.rtcm_ignored.values()),
                     "rtcm_malformed": sum(self.rtcm_malformed.values()), "unread_bytes": self.unread_bytes}
        ages = self.correction_ages_s
        if ages:
            p50, p95 = np.percentile(ages, [50, 95])
            out.update(corrections_read=len(ages), correction_age_p50_s=round(float(p50), 3),
                       correction_age_p95_s=round(float(p95), 3), correction_age_max_s=round(max(ages), 3))
        if rover is not None:
            out.update(solution=rover.status.phase, base_id=rover.status.base_id or None)
        return out

    # -- ByteTwin (COM1) -----------------------------------------------------------------
    def on_connect(self, now_s: float) -> None:
        self.port_connect(ComPort.COM1, now_s)

    def feed(self, data: bytes, now_s: float) -> None:
        with self._lock:
            self._feed(self.com1, data, now_s)

    def poll(self, now_s: float) -> bytes:
        with self._lock:
            self.clock.ensure(now_s)
            if self._reset_at is not None and now_s >= self._reset_at:
                said = bytes(self._out)             # the RESET's own response still goes out
                self._reboot(now_s)
                return said
            if now_s < self._boot_until:
                return b""
            self._read_corrections(now_s)
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
        for port in (self.com1, self.com2):
            carried = port.line.idle_s()        # corrections on a line: read them when there
            if carried is not None:
                due = min(due, carried)
        return max(due, now_s)

    # -- any port ---------------------------------------------------------------------
    def port_connect(self, com: ComPort, now_s: float) -> None:
        """A new connection. On COM1, what the driver's double break does (COM §2.6.10): its
        non-held logs stop, its buffers are cleared, its rate and modes are the factory's. On
        another port nothing: the driver sends no break down its corrections port, which keeps
        what COM1's commands set (COM COM2, INTERFACEMODE COM2)."""
        with self._lock:
            self.clock.ensure(now_s)
            if com == ComPort.COM1:
                self.logs = {k: v for k, v in self.logs.items() if v.hold}
                self.com1.break_()

    def port_feed(self, com: ComPort, data: bytes, now_s: float) -> None:
        with self._lock:
            self._feed(self.ports[com], data, now_s)

    def port_poll(self, com: ComPort, now_s: float) -> bytes:
        if com == ComPort.COM1:
            return self.poll(now_s)
        with self._lock:
            self.clock.ensure(now_s)
            if now_s < self._boot_until:
                return b""
            self._read_corrections(now_s)
            port = self.ports[com]
            out = bytes(port.out)
            port.out.clear()
            return out

    def port_next_due(self, com: ComPort, now_s: float) -> float:
        if com == ComPort.COM1:
            return self.next_due(now_s)
        port = self.ports[com]
        if port.out:
            return now_s
        due = now_s + 0.1
        carried = port.line.idle_s()
        return due if carried is None else max(now_s, min(due, carried))

    def _feed(self, port: ReceiverPort, data: bytes, now_s: float) -> None:
        self.clock.ensure(now_s)
        if now_s < self._boot_until:
            return                              # deaf while it boots
        if port.takes_commands:
            port.rx += data
            self._parse_commands(now_s, port)
            if port.takes_commands or not port.rx:
                return
            data = bytes(port.rx)               # what followed an INTERFACEMODE that took commands away
            port.rx.clear()
        if port.rxtype == InterfaceMode.RTCMV3:
            port.line.send(data, now_s, port.baud)
            self._read_corrections(now_s)
        else:
            self.unread_bytes += len(data)      # NONE, or corrections this twin does not decode

    # -- corrections ------------------------------------------------------------------
    def _read_corrections(self, now_s: float) -> None:
        """What the RTCMV3 ports' lines have carried by now, read by the receiver."""
        for port in (self.com1, self.com2):
            if port.rxtype != InterfaceMode.RTCMV3:
                continue
            data = port.line.receive(now_s)
            if not data:
                continue
            messages = port.rtcm.feed(data)
            rover = self._rover_for_corrections() if messages else None
            if rover is None:
                continue
            gps_ms = self._gps_ms(now_s)
            for m in messages:
                if isinstance(m, BasePosition):
                    rover.base_position(gps_ms, m.base_id, m.ecef_m)
                else:
                    rover.observe(gps_ms, m.tow_ms, m.base_id, m.l2)

    def _rover_for_corrections(self) -> Rover | None:
        """The receiver's differential side, made when it first reads corrections (until
        then its solutions are exactly those of a receiver that takes none)."""
        if self._rover is None and self.solver is not None:
            self._rover = Rover(self.solver.errors, self.engine, seed=self.seed, figures=self.rtk_figures)
            self._apply_correction_settings()
            self.solver.rover = self._rover
        return self._rover

    def _apply_correction_settings(self) -> None:
        if self._rover is not None:
            machine = self._rover.machine
            machine.dgps_timeout_s = self.dgps_timeout_s
            machine.psr_source, machine.rtk_source = self.psr_source, self.rtk_source

    # -- time ------------------------------------------------------------------------
    def _gps_ms(self, now_s: float) -> int:
        return self.clock.gps_ms(now_s)

    def _header(self, message_id: int, gps_ms: int, *, message_type=BINARY_MESSAGE_TYPE,
                sequence: int = 0, time_status: TimeStatus | None = None, port_address: int = OWN_PORT) -> Header:
        time_status, week, ms = self._time_tag(gps_ms, time_status)
        return Header(message_id, message_type=message_type, port_address=port_address,
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
        assert self.solver is not None, "solved only without a replay: then the twin was given truth"
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
        replay = self.replay
        assert replay is not None, "called for a twin that replays"
        replay.begin(now_s, self._gps_ms(now_s))
        if not replay.retime:                   # the receiver lives in the recording's time
            self.clock.anchor(now_s, replay.host_gps_ms(0))

    def _replay_due(self, now_s: float) -> None:
        assert self.replay is not None, "called for a twin that replays"
        for solution in self.replay.due(now_s):
            self._last_solution = solution
            due = [m for m, e in self.logs.items() if e.fires_at(solution.gps_ms, EPOCH_MS)]
            if due:
                self._emit(due, solution)
                self._drop_onnext(due)

    # -- commands --------------------------------------------------------------------
    def _parse_commands(self, now_s: float, port: ReceiverPort) -> None:
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
                self.checksum_errors += 1
                self._respond(header, now_s, Rejected(ResponseId.INVALID_CHECKSUM), port)
                continue
            if header.is_response or header.message_format != 0:
                continue                        # only binary commands are understood
            self._execute(header, frame[header.header_length:-CRC_LENGTH], now_s, port)

    def _respond(self, header: Header, now_s: float, result: Rejected | None, port: ReceiverPort) -> None:
        response = (Response(ResponseId.OK, "OK") if result is None
                    else Response(result.response_id, result.text))
        self.history.append((MessageId(header.message_id).name, response.text))
        if not port.responses:
            return                              # INTERFACEMODE ... OFF: no responses on this port
        out = self._header(header.message_id, self._gps_ms(now_s),
                           message_type=header.message_type, sequence=header.sequence, port_address=port.address)
        port.out += response.frame(out)

    def _execute(self, header: Header, body: bytes, now_s: float, port: ReceiverPort) -> None:
        cls = COMMANDS.get(header.message_id)
        after = None
        self._cmd_port = port
        try:
            if cls is None:
                raise Rejected(ResponseId.INVALID_MESSAGE_ID)
            try:
                command = cls.from_body(body)
            except BodyError:
                raise Rejected(ResponseId.MESSAGE_MISSING_FIELD) from None
            after = self._HANDLERS[cls](self, command, now_s)
        except Rejected as rejected:
            self._respond(header, now_s, rejected, port)
            return
        self._respond(header, now_s, None, port)
        if after is not None:
            after()

    def _on_com1(self, port: int) -> bool:
        """Whether a LOG/UNLOG port field names COM1, where this twin's logs come out."""
        return port == OWN_PORT or (port == Port.THISPORT and self._cmd_port is self.com1)

    def _com_port(self, com: int) -> ReceiverPort | None:
        """The port a COM or INTERFACEMODE port field (Table 15) names, if the twin has it."""
        if com == ComPort.THISPORT:
            return self._cmd_port
        return self.ports.get(com)

    def _log_port(self, port: int) -> ReceiverPort | None:
        """The port a LOG port field (Table 5) sends a polled log to, if the twin has it."""
        if port == Port.THISPORT:
            return self._cmd_port
        return next((p for p in self.ports.values() if p.address == port), None)

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
        if cmd.message == MessageId.VERSION:
            return self._version(cmd, now_s)
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
        if not self._on_com1(cmd.port):
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
        if self._on_com1(cmd.port):
            if cmd.message not in self.logs:
                raise Rejected(ResponseId.LOG_DOES_NOT_EXIST)
            del self.logs[MessageId(cmd.message)]     # (one of the logs': a MessageId)
        return None

    def _unlogall(self, cmd: Unlogall, now_s: float):
        self._check(2, self._known(cmd.port))
        self._check(3, cmd.held in (0, 1))
        here = self._cmd_port is self.com1 and cmd.port == Port.THISPORT_ALL
        if here or (cmd.port in OWN_UNLOGALL and cmd.port != Port.THISPORT_ALL) or self._on_com1(cmd.port):
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
        port = self._com_port(cmd.port)
        if port is None:
            return None

        def switch():                           # the response still goes at the old rate
            port.baud = cmd.baud
        return switch

    def _interfacemode(self, cmd: InterfaceModeCommand, now_s: float):
        """INTERFACEMODE (§2.6.28): what a port takes from now on, after the response."""
        self._check(2, self._known(cmd.port) and cmd.port != ComPort.ALL)
        self._check(3, self._known(cmd.rxtype))
        self._check(4, self._known(cmd.txtype))
        self._check(5, cmd.responses in (0, 1))
        port = self._com_port(cmd.port)
        if port is None:
            return None

        def switch():
            port.rxtype, port.txtype = InterfaceMode(cmd.rxtype), InterfaceMode(cmd.txtype)
            port.responses = bool(cmd.responses)
            port.line.clear()
            port.rtcm.clear()
        return switch

    def _dgpstimeout(self, cmd: DgpsTimeout, now_s: float):
        """DGPSTIMEOUT (§2.6.16): the oldest pseudorange corrections used, 2-1000 s."""
        self._check(2, 2 <= cmd.delay <= 1000, ResponseId.PARAMETER_OUT_OF_RANGE)
        self.dgps_timeout_s = float(cmd.delay)
        self._apply_correction_settings()
        return None

    def _source(self, cmd: PsrDiffSource | RtkSource, now_s: float):
        """PSRDIFFSOURCE / RTKSOURCE (§2.6.40, §2.6.47): whose corrections count. A new
        PSRDIFFSOURCE drops the corrections in use at once (§2.6.40 note 1)."""
        self._check(2, self._known(cmd.type) and not (isinstance(cmd, PsrDiffSource) and cmd.type == DgpsType.CMR))
        self._check(3, not source_id_error(cmd.type, cmd.id))
        source = Source(int(cmd.type), cmd.id)
        if isinstance(cmd, PsrDiffSource):
            self.psr_source = source
            if self._rover is not None:
                self._rover.machine.drop_corrections(self._gps_ms(now_s) / 1000.0)
        else:
            self.rtk_source = source
        self._apply_correction_settings()
        return None

    def _version(self, cmd: Log, now_s: float):
        """LOG VERSION ONCE (§3.4.94, a polled log): the receiver's one component."""
        self._check(4, (cmd.message_type >> 5) & 0x3 == MessageFormat.BINARY)
        if cmd.trigger != Trigger.ONCE:
            raise Rejected(ResponseId.TRIGGER_NOT_VALID, Trigger(cmd.trigger).name)
        port = self._log_port(cmd.port)
        if port is None:
            return None

        def output():
            header = self._header(MessageId.VERSION, self._gps_ms(now_s), port_address=port.address)
            port.out += encode_frame(header, Version((self.version,)).body())
        return output

    def _dynamics(self, cmd: DynamicsCommand, now_s: float):
        self._check(2, self._known(cmd.dynamics))
        self.dynamics = Dynamics(cmd.dynamics)     # (read as a Dynamics already: the same member)
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
        ports = tuple((p.com, p.baud, p.rxtype, p.txtype, p.responses) for p in self.ports.values())
        self.saved = ReceiverConfig(tuple(self.logs.values()), self.baud, self.dynamics, self.sbas, ports,
                                    self.dgps_timeout_s, self.psr_source, self.rtk_source)
        return None

    # -- RXCONFIG ----------------------------------------------------------------------
    def _rxconfig(self, cmd: Log, now_s: float):
        """LOG RXCONFIG ONCE: after the response, one RXCONFIG log per setting."""
        fmt = (cmd.message_type >> 5) & 0x3
        self._check(4, fmt in (MessageFormat.BINARY, MessageFormat.ASCII))
        if cmd.trigger != Trigger.ONCE:
            raise Rejected(ResponseId.TRIGGER_NOT_VALID, Trigger(cmd.trigger).name)
        if not self._on_com1(cmd.port):
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
        return out + self._correction_settings()

    def _correction_settings(self) -> list[tuple[Command, str]]:
        """The settings for corrections that differ from the factory's (so a receiver told
        nothing of corrections lists what it listed before they were modelled)."""
        out: list[tuple[Command, str]] = []
        for p in self.ports.values():
            if p.com != ComPort.COM1 and p.baud != FACTORY_BAUD:
                out.append((Com(p.com, p.baud), f"{p.name},{p.baud},N,8,1,N,OFF,ON"))
            if (p.rxtype, p.txtype, p.responses) != (InterfaceMode.NOVATEL, InterfaceMode.NOVATEL, True):
                out.append((InterfaceModeCommand(p.com, p.rxtype, p.txtype, int(p.responses)),
                            f"{p.name},{p.rxtype.name},{p.txtype.name},{'ON' if p.responses else 'OFF'}"))
        if self.dgps_timeout_s != FACTORY_DGPS_TIMEOUT_S:
            out.append((DgpsTimeout(int(self.dgps_timeout_s)), f"{self.dgps_timeout_s:.0f}"))
        for cls, source in ((PsrDiffSource, self.psr_source), (RtkSource, self.rtk_source)):
            if source != Source():
                out.append((cls(source.type, source.id), f"{DgpsType(source.type).name},\"{source.id}\""))
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

    #: each command's handler: (twin, command, now_s) -> what to do after the response, or None
    _HANDLERS: dict[type, Callable[..., Callable[[], None] | None]] = {
        Log: _log, Unlog: _unlog, Unlogall: _unlogall, Com: _com,
        DynamicsCommand: _dynamics, SbasControl: _sbascontrol, Reset: _reset,
        SaveConfig: _saveconfig, InterfaceModeCommand: _interfacemode, DgpsTimeout: _dgpstimeout,
        PsrDiffSource: _source, RtkSource: _source}

    def _reboot(self, now_s: float) -> None:
        """RESET: silent while booting, then the saved configuration (or the factory's),
        and no fix until the receiver has acquired satellites again."""
        self._reset_at = None
        self._boot_until = now_s + self.boot_s
        config = self.saved or ReceiverConfig()
        self.logs = {e.message: replace(e) for e in config.logs}
        for p in self.ports.values():
            p.break_()
        for com, baud, rxtype, txtype, responses in config.ports:
            p = self.ports[com]
            p.baud, p.rxtype, p.txtype, p.responses = baud, rxtype, txtype, responses
        self.baud, self.dynamics, self.sbas = config.baud, config.dynamics, config.sbas
        self.dgps_timeout_s, self.psr_source, self.rtk_source = (config.dgps_timeout_s, config.psr_source,
                                                                 config.rtk_source)
        self._apply_sbas()
        self._next_epoch_ms = None
        self._last_solution = None
        if self._rover is not None:             # what it had of the corrections is gone
            assert self.solver is not None, "a rover is made for the truth's solver"
            self._rover = None
            self.solver.rover = None
        if self.solver is not None:
            self._boot_gps_ms = self._gps_ms(self._boot_until)
            self.solver.cold_start(self._boot_gps_ms + int(self.reset_cold_start_s * 1000))
