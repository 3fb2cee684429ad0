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

This module is the receiver's ports, clock, boot and RESET; its parts live beside it: the
command interpreter (novatel_commands.py), RXCONFIG (novatel_rxconfig.py), the logs held and
their output at each epoch (novatel_logs.py), the corrections port (novatel_corrections.py;
the RTK solution-type machine is rtk.py).
"""
from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from viena.common.twin.serial_port import ByteTwin
from viena.services.gnss.driver.novatel.enums import (
    ComponentType,
    ComPort,
    Dynamics,
    InterfaceMode,
    MessageId,
    Port,
    PositionType,
    SbasKeyword,
    SbasSystem,
)
from viena.services.gnss.driver.novatel.logs import Component

from .clock import GpsClock
from .errors import CommonErrors, GnssErrorModel, SkyModel
from .novatel_commands import CommandInterpreter
from .novatel_corrections import CorrectionsIntake
from .novatel_logs import LogEntry, LogOutput, ReceiverConfig
from .ports import LINE_BUFFER_BYTES, PortTwin, ReceiverPort
from .replay import DriveReplay, RecordedEpoch
from .rover import Rover
from .rtk import DEFAULT_FIGURES, FACTORY_DGPS_TIMEOUT_S, RtkFigures, Source, engine_of_model
from .solution import TruthSolver

#: The receiver VERSION describes by default: vol. 2 §3.4.94's example, an RT-2 OEM4-G2
#: ("RT2WA", "OEM4g2-2.00-X2T"), on the manual's firmware.
DEFAULT_MODEL = "RT2WA"
DEFAULT_FIRMWARE = "2.310"


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
        # ports, line and clock
        self.com1 = ReceiverPort(ComPort.COM1, Port.COM1)
        self.com2 = ReceiverPort(ComPort.COM2, Port.COM2)
        self.ports: dict[int, ReceiverPort] = {ComPort.COM1: self.com1, ComPort.COM2: self.com2}   # by port field
        for p in self.ports.values():
            p.line.buffer_bytes = line_buffer_bytes
        self._rx = self.com1.rx
        self._out = self.com1.out
        self._lock = threading.Lock()               # COM1 and COM2 may be served from two threads
        self.clock = GpsClock()
        self.output = LogOutput(self)
        self.commands = CommandInterpreter(self)
        self.corrections = CorrectionsIntake(self)          # its rover made when the first corrections are read
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
        return self.corrections.rover

    @property
    def correction_ages_s(self) -> list[float]:
        """Every observables message's age when the receiver read it: its GPS time at the
        read minus the base's epoch (s), oldest first."""
        rover = self.corrections.rover
        return [] if rover is None else list(rover.correction_ages_s)

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
        """What corrections came to, for the sim's health ({} while none came)."""
        return self.corrections.health()

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
            self.corrections.read(now_s)
            if self.replay is not None:
                self.output.replay_due(now_s)
            else:
                self.output.solve_due(now_s)
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
        elif self.logs and self.output.next_epoch_ms is not None:
            due = min(due, self.clock.now_of(self.output.next_epoch_ms) + self.output_delay_s)
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
            self.corrections.read(now_s)
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
            self.commands.parse(now_s, port)
            if port.takes_commands or not port.rx:
                return
            data = bytes(port.rx)               # what followed an INTERFACEMODE that took commands away
            port.rx.clear()
        if port.rxtype == InterfaceMode.RTCMV3:
            port.line.send(data, now_s, port.baud)
            self.corrections.read(now_s)
        else:
            self.unread_bytes += len(data)      # NONE, or corrections this twin does not decode

    def _gps_ms(self, now_s: float) -> int:
        return self.clock.gps_ms(now_s)

    def _apply_sbas(self) -> None:
        if self.solver is None:
            return
        using = self.sbas.keyword == SbasKeyword.ENABLE and self.sbas.system != SbasSystem.NONE
        self.solver.pos_type = PositionType.WAAS if using else PositionType.SINGLE
        self.solver.errors.set_cep(self.sbas_cep_m if using else self.cep_m)

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
        self.output.next_epoch_ms = None
        self.output.last_solution = None
        if self.corrections.rover is not None:  # what it had of the corrections is gone
            assert self.solver is not None, "a rover is made for the truth's solver"
            self.corrections.rover = None
            self.solver.rover = None
        if self.solver is not None:
            self._boot_gps_ms = self._gps_ms(self._boot_until)
            self.solver.cold_start(self._boot_gps_ms + int(self.reset_cold_start_s * 1000))
