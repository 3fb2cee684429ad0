"""`viena-gnss`: one GNSS receiver's fixes on viena/<car>/gnss/<unit>/fix.

    viena-gnss --unit gnss0 --port /dev/ttyUSB0                  # NovAtel OEM4, binary
    viena-gnss --unit gps0 --port socket://127.0.0.1:5002 --protocol nmea

The driver does the bytes; this process configures the receiver (the car's start-up
sequence), turns its logs into samples, and keeps going whatever the device does: the
device supervisor (common/supervisor.py) reports a port that fails or a receiver that goes
silent in health, closes it, and reopens it with a backoff capped at ``reconnect_max_s``,
so data flows again within a second of the device coming back. Health counts frames, CRC
errors, resyncs, command failures, the supervisor's reconnects and failures, and the age
of the last fix.

Corrections (NovAtel, setting `corrections`): the receiver's VERSION says what its model and
firmware take (driver/novatel/corrections.py); a format it cannot take is refused in one
line and the fixes stay single-point; else the start-up configures it and the samples on
viena/<car>/gnss/corrections go to its port (the logs' own or a second one) through a
writer thread that drops what the receiver cannot decode and what the line cannot carry
(driver/novatel/feed.py, writer.py), each counted in health.
"""
from __future__ import annotations

import itertools
import threading
from abc import abstractmethod
from dataclasses import dataclass, replace
from urllib.parse import urlsplit

import serial

from viena.common import clock
from viena.common.errors import ConfigError, SampleError
from viena.common.log import Throttled
from viena.common.rtcm3 import family
from viena.common.samples import topics
from viena.common.samples.corrections import CORRECTIONS, read_corrections
from viena.common.samples.fix import solution_kind
from viena.common.service import Service, run_service
from viena.common.settings import setting
from viena.common.silence import SilenceWatch
from viena.common.supervisor import Backoff, Device, DeviceSupervisor
from viena.services.gnss.driver.nmea import NmeaReceiver
from viena.services.gnss.driver.novatel import (
    CommandError,
    CommandTimeout,
    ComPort,
    Dynamics,
    LogRequest,
    MessageId,
    NovatelReceiver,
    SbasKeyword,
    SbasSystem,
    StartupConfig,
    Trigger,
    check_sbas,
    source_id_error,
)
from viena.services.gnss.driver.novatel.corrections import FORMATS, RTCM3_DECODED
from viena.services.gnss.driver.novatel.enums import DgpsType
from viena.services.gnss.driver.novatel.feed import DROP_REASONS, CorrectionsFeed, Taken, line_bytes_per_s
from viena.services.gnss.driver.novatel.startup import CorrectionsSetup
from viena.services.gnss.driver.novatel.writer import CorrectionsWriter, SecondPort
from viena.services.gnss.fixes import NovatelFixBuilder, fix_from_nmea

USAGE = __doc__
LOGGED = ("BESTXYZ", "BESTPOS", "BESTVEL")
CONNECT_ERRORS = (CommandError, CommandTimeout, serial.SerialException, OSError, ValueError)
WATCH_PERIOD_S = 0.1
#: how long after a start-up the receiver's RXCONFIG may take to confirm SBASCONTROL
SBAS_CONFIRM_S = 5.0
FIRST_RETRY_S = 0.05
#: the receiver's ports a second corrections port may be (Table 15)
CORRECTIONS_PORTS = ("COM1", "COM2", "COM3", "AUX")
#: URL schemes pyserial sends no break on (common/link.py: carries_break)
BREAKLESS_SCHEMES = ("socket", "loop")
#: how often a repeating corrections problem (flood, wrong format, garbage) is said again
CORRECTIONS_LINE_S = 60.0
#: solution kinds that show the receiver uses the corrections
DIFFERENTIAL_KINDS = ("dgps", "float", "fixed")


@dataclass(frozen=True)
class GnssSettings:
    """[gnss] and [gnss.<unit>]: one receiver, its start-up and how long it may be silent."""
    port: str = setting("", "pyserial URL of the receiver: /dev/ttyUSB0, socket://HOST:PORT, "
                            "rfc2217://HOST:PORT", metavar="URL")
    protocol: str = setting("novatel", "NovAtel OEM4 binary or NMEA 0183", choices=("novatel", "nmea"))
    baudrate: int = setting(115200, "working rate (NovAtel: set by COM; NMEA: opened at)",
                            flags=("--baud",))
    initial_baudrate: int = setting(9600, "NovAtel: the factory rate, what a break restores")
    send_break: str = setting("auto", "NovAtel: a break first (auto: not on socket://)",
                              choices=("auto", "on", "off"))
    logs: tuple[str, ...] = setting(("BESTXYZ",), "NovAtel logs: BESTXYZ, or BESTPOS and BESTVEL",
                                    choices=LOGGED)
    trigger: str = setting("ONTIME", "NovAtel: when the logs come", choices=Trigger.__members__)
    period_s: float = setting(0.05, "NovAtel: period of the logs (20 Hz)")
    dynamics: str = setting("AIR", "NovAtel: receiver dynamics (the manual advises AIR)",
                            choices=Dynamics.__members__)
    sbas: str = setting("ENABLE", "NovAtel: SBAS corrections (\"\": leave the receiver's)",
                        choices=("", *SbasKeyword.__members__))
    sbas_system: str = setting("AUTO", "NovAtel: which SBAS system", choices=SbasSystem.__members__)
    sbas_enable_value: int = setting(0, "NovAtel: the binary SBASCONTROL keyword the firmware reads "
                                        "as ENABLE (OEM4 2.310 manual: 0; later firmware: 1); the "
                                        "receiver's RXCONFIG confirms it", choices=(0, 1))
    command_timeout_s: float = setting(1.0, "NovAtel: longest wait for a command's response")
    silence_timeout_s: float = setting(1.0, "nothing decoded for this long: reconnect ...")
    silence_epochs: float = setting(3.0, "... or this many epoch intervals, if longer (0: off)")
    reconnect_max_s: float = setting(0.5, "longest wait between attempts to reopen the port")
    nmea_uere_m: float = setting(3.0, "NMEA: sigmas are DOP times this user range error")
    corrections: str = setting("", "NovAtel: differential corrections from viena/<car>/gnss/corrections "
                                   "to the receiver in this format (\"\": none)", choices=("", *FORMATS))
    corrections_port: str = setting("", "NovAtel: pyserial URL of the receiver's port for them (\"\": the "
                                        "logs' port, which then takes no commands until a break)", metavar="URL")
    corrections_port_name: str = setting("COM2", "NovAtel: that port as the receiver names it",
                                         choices=CORRECTIONS_PORTS)
    corrections_baudrate: int = setting(0, "NovAtel: that port's rate, set by COM (0: the working rate)")
    dgps_timeout_s: int = setting(60, "NovAtel: DGPSTIMEOUT, oldest pseudorange corrections used, 2-1000 s "
                                      "(RTK's is 60 s, fixed)")
    corrections_source_id: str = setting("ANY", "NovAtel: base station to take them from (RTKSOURCE, "
                                                "PSRDIFFSOURCE): ANY or its id")
    corrections_check: bool = setting(True, "NovAtel: refuse a format the receiver's VERSION (model, "
                                            "firmware) does not take; false: a model the table does not know")


class ReceiverDevice(Device):
    """What both receivers share under the supervisor: their reader thread reports a port
    that failed, which `serve` raises in the supervisor's thread, and every frame or
    sentence they decode is a sign of life."""

    protocol = ""
    connect_errors = CONNECT_ERRORS

    def __init__(self, service: GnssService):
        self.service = service
        self._failed = clock.Event()
        self._failure = ""

    def link_failed(self, exc: Exception) -> None:
        """The driver's port failed (called from its reader thread)."""
        self._failure = str(exc) or type(exc).__name__
        self._failed.set()

    def connect(self, again: bool) -> None:
        self._failed.clear()
        self._start(again)

    def serve(self, timeout_s: float) -> None:
        """The reader thread does the work; here only wait, and pass on what it saw."""
        if self._failed.wait(timeout_s):
            raise serial.SerialException(self._failure)
        self.service.silence.heard(self.last_rx_ns())

    @abstractmethod
    def _start(self, again: bool) -> None:
        """Open (and configure) the receiver."""

    @abstractmethod
    def last_rx_ns(self) -> int:
        """Host time of the last frame or sentence the driver decoded."""


class NovatelSource(ReceiverDevice):
    """A NovAtel OEM4 receiver: start-up sequence, BESTXYZ (or BESTPOS+BESTVEL) to fixes."""

    protocol = "novatel"
    kind = "NovAtel receiver"

    def __init__(self, service: GnssService):
        super().__init__(service)
        s = service.settings
        self.receiver = NovatelReceiver(s.port, command_timeout=s.command_timeout_s,
                                        on_log=self._on_log, on_link_error=self.link_failed)
        send_break = {"auto": None, "on": True, "off": False}[s.send_break]
        logs = tuple(LogRequest(MessageId[name], Trigger[s.trigger], s.period_s) for name in s.logs)
        self.corrections = ReceiverCorrections(service, self.receiver) if s.corrections else None
        self.config = StartupConfig(
            initial_baud=s.initial_baudrate, baud=s.baudrate, send_break=send_break,
            dynamics=Dynamics[s.dynamics], sbas=SbasKeyword[s.sbas] if s.sbas else None,
            sbas_system=SbasSystem[s.sbas_system], sbas_enable_value=s.sbas_enable_value,
            logs=logs, read_config=True, ask_version=True,
            corrections=self.corrections.setup() if self.corrections else CorrectionsSetup())
        self._said_version = ""
        self._sbas_since = clock.monotonic()
        self._sbas_verdict = ""
        service.health.error("sbas_mismatches", 0)
        service.health.error("sbas_unconfirmed", 0)
        self.builder = NovatelFixBuilder(service.unit, join_bestvel="BESTVEL" in s.logs)
        #: the log that marks an epoch: the one the fixes are made from
        self.epoch_log = MessageId.BESTXYZ if "BESTXYZ" in s.logs else MessageId.BESTPOS

    def _start(self, again: bool) -> None:
        """The start-up sequence. Coming back after a lost link, first try the receiver
        as it most likely still is (working rate, no 2 s break), then the whole sequence."""
        self._sbas_since, self._sbas_verdict = clock.monotonic(), ""
        if self.corrections is not None:
            self.corrections.detach()               # nothing goes to a port being set up
        if again and self.config.send_break is not False:
            quick = replace(self.config, send_break=False, initial_baud=self.config.baud)
            try:
                self.receiver.startup(quick)
                self._started()
                return
            except CommandTimeout:
                self.receiver.close()
        self.receiver.startup(self.config)
        self._started()

    def _started(self) -> None:
        """What the start-up learnt: the receiver's model and firmware, in health and once
        in the log; and the corrections' fate."""
        rx, health = self.receiver, self.service.health
        ability = rx.ability
        if ability is not None:
            health.set("receiver_model", ability.model)
            health.set("receiver_firmware", ability.firmware)
            health.set("receiver_rtk", ability.rtk or "none")
            health.set("receiver_formats", list(ability.formats))
            said = f"receiver {ability.summary()}"
        else:
            said = f"receiver model unknown: {rx.version_error or 'no VERSION'}"
        health.set("receiver_version_error", rx.version_error)
        if said != self._said_version:
            self._said_version = said
            self.service.log.info("%s: %s", self.service.unit, said)
        if self.corrections is not None:
            self.corrections.started()

    def serve(self, timeout_s: float) -> None:
        super().serve(timeout_s)
        self._report_sbas()

    def _report_sbas(self) -> None:
        """SBAS as the receiver's RXCONFIG says it holds it, against what was asked: in
        health (state sbas, sbas_confirmed; errors sbas_mismatches, sbas_unconfirmed) and
        one log line each time the verdict changes."""
        check = check_sbas(self.config, self.receiver.sbas(), wait_s=SBAS_CONFIRM_S,
                           waited_s=clock.monotonic() - self._sbas_since,
                           request_error=self.receiver.config_request_error)
        if check.verdict == self._sbas_verdict:
            return
        self._sbas_verdict = check.verdict
        health, log = self.service.health, self.service.log
        health.set("sbas", check.reported)
        health.set("sbas_confirmed", check.confirmed)
        if check.verdict == "mismatch":
            health.error("sbas_mismatches")
            log.error("SBAS is not as configured: %s", check.why)
        elif check.verdict == "unconfirmed":
            health.error("sbas_unconfirmed")
            log.warning("SBAS setting not confirmed by the receiver: %s", check.why)
        elif check.verdict == "confirmed":
            log.info("the receiver holds SBASCONTROL %s", check.reported)

    def disconnect(self) -> None:
        if self.corrections is not None:
            self.corrections.detach()
        self.receiver.close()

    def shutdown(self) -> None:
        if self.corrections is not None:
            self.corrections.detach()
        self.receiver.shutdown()

    def last_rx_ns(self) -> int:
        return self.receiver.last_frame_host_ns

    def counters(self) -> tuple[dict, dict]:
        st = self.receiver.stats
        counts = {"frames": st.frames, "logs": st.logs, "responses": st.responses,
                  "unknown_messages": st.unknown_messages}
        errors = {"crc_errors": st.crc_errors, "length_errors": st.length_errors,
                  "resyncs": st.resyncs, "discarded_bytes": st.discarded_bytes,
                  "body_errors": st.body_errors, "unmatched_responses": st.unmatched_responses,
                  "command_failures": st.command_failures, "dropped_logs": st.dropped_logs}
        return counts, errors

    def _on_log(self, message) -> None:
        if message.header.message_id == self.epoch_log:
            self.service.silence.epoch(message.t_host_ns)
        self.service.publish_all(lambda: self.builder.add(message))


class ReceiverCorrections:
    """The corrections path of one NovAtel receiver: samples from the subscriber to the
    writer thread, what each start-up decided to health and the log (a refusal in one line),
    the feed's counters to health (errors `corrections_dropped_<reason>` in bytes)."""

    #: no sample for this long: the state says "waiting" instead of "flowing"
    STALE_S = 5.0

    def __init__(self, service: GnssService, receiver: NovatelReceiver):
        s = service.settings
        self.service, self.receiver, self.unit = service, receiver, service.unit
        self.format = s.corrections
        self.baud = (s.corrections_baudrate or s.baudrate) if s.corrections_port else s.baudrate
        self.port_name = s.corrections_port_name if s.corrections_port else ""
        self.feed = CorrectionsFeed(self.format, RTCM3_DECODED if self.format == "RTCMV3" else None,
                                    line_bytes_per_s(self.baud))
        self.second = SecondPort(s.corrections_port, self.baud) if s.corrections_port else None
        self.writer = CorrectionsWriter(self.feed, on_taken=self._on_taken, on_port_error=self._on_port_error,
                                        on_tick=self._report, name=f"{self.unit}-corrections")
        self._last_sample_s: float | None = None
        #: a fix since the last start-up had a differential solution type
        self._differential_seen = False
        self._said_refusal = ""
        self._synced: dict[str, int] = {}
        self._report_lock = threading.Lock()        # the writer's thread and the supervisor's
        self._lines = Throttled(service.log, f"{self.unit}: corrections", CORRECTIONS_LINE_S)
        health = service.health
        for reason in DROP_REASONS:
            (health.count if reason == "type" else health.error)(f"corrections_dropped_{reason}", 0)
        for name in ("corrections_refused", "corrections_bad_samples"):
            health.error(name, 0)
        health.set("corrections", self.format)
        health.set("corrections_port", s.corrections_port or "logs")
        health.set("corrections_state", "starting")
        health.set("corrections_refused", "")

    def setup(self) -> CorrectionsSetup:
        s = self.service.settings
        return CorrectionsSetup(
            format=self.format, port=ComPort[s.corrections_port_name] if s.corrections_port else None,
            baud=self.baud if s.corrections_port else 0, dgps_timeout_s=s.dgps_timeout_s,
            source_id=s.corrections_source_id, check=s.corrections_check)

    def start(self) -> None:
        self.writer.start()

    def stop(self) -> None:
        self.writer.stop()
        if self.second is not None:
            self.second.close()

    def detach(self) -> None:
        self.writer.attach(None)

    def started(self) -> None:
        """After a start-up: write to the port if the receiver took the format, else say
        why not (once per reason) and keep single-point."""
        rx, health, log = self.receiver, self.service.health, self.service.log
        self._differential_seen = False
        refused = rx.corrections_refused
        health.set("corrections_refused", refused)
        if refused:
            health.error("corrections_refused")
            if refused != self._said_refusal:
                self._said_refusal = refused
                log.error("%s: corrections %s refused: %s", self.unit, self.format, refused)
            self._report()
            return
        if not rx.corrections_format:
            return
        self._said_refusal = ""
        where = f"{self.port_name} ({self.second.url})" if self.second is not None else "the logs' port"
        log.info("%s: corrections %s to %s at %d baud (at most %.0f B/s)", self.unit, self.format, where,
                 self.baud, self.feed.budget.rate)
        self.writer.attach(self.second.write if self.second is not None else rx.write_corrections)
        self._report()

    def fix_kind(self, kind: str) -> None:
        """A fix's solution kind (the reader's thread): a differential one confirms that
        the receiver takes the corrections."""
        if kind in DIFFERENTIAL_KINDS:
            self._differential_seen = True

    # -- the subscriber (zenoh's thread: never blocks) ----------------------------------------
    def on_sample(self, sample) -> None:
        try:
            got = read_corrections(CORRECTIONS.decode(sample.payload.to_bytes()))
        except SampleError as exc:
            self.service.health.error("corrections_bad_samples")
            self._lines.log("bad sample", str(exc))
            return
        self._last_sample_s = clock.monotonic()
        self.service.health.set("corrections_source", got.source)
        self.service.health.set("corrections_base_id", got.base_id)
        self.writer.put(got.data, got.format)

    # -- the writer's thread -------------------------------------------------------------------
    def _on_taken(self, taken: Taken) -> None:
        if taken.new_dropped_types:
            self.service.log.warning("%s: %s", self.unit, self._dropping_line(taken.new_dropped_types))
        if taken.flooded:
            self._lines.log("more than the line carries", f"{self.baud} baud: at most "
                            f"{self.feed.budget.rate:.0f} B/s; dropping whole frames")
        if taken.wrong_format:
            self._lines.log("wrong format", f"RTCM 3 frames came, the receiver takes {self.format}: dropped")
        self._report()

    def _on_port_error(self, exc: Exception) -> None:
        self._lines.log("port failed", str(exc))

    def _dropping_line(self, types: list[int]) -> str:
        """'dropping RTCM 1074, 1084 (MSM): firmware 2.310 decodes 1001-1006'."""
        by_family: dict[str, list[int]] = {}
        for t in sorted(types):
            by_family.setdefault(family(t), []).append(t)
        named = "; ".join(f"{', '.join(map(str, ts))} ({name})" for name, ts in by_family.items())
        ability = self.receiver.ability
        firmware = f"firmware {ability.firmware_number}" if ability is not None else "the OEM4"
        return f"dropping RTCM {named}: {firmware} decodes {min(RTCM3_DECODED)}-{max(RTCM3_DECODED)}"

    def _report(self) -> None:
        """The feed's counters and the sample's age to health."""
        with self._report_lock:
            self._report_locked()

    def _report_locked(self) -> None:
        health, c = self.service.health, self.feed.counts
        totals = {"corrections_samples": c.samples, "corrections_bytes_in": c.bytes_in,
                  "corrections_bytes_written": c.bytes_written, "corrections_frames_written": c.frames_written}
        for name, total in totals.items():
            health.count(name, total - self._synced.get(name, 0))
            self._synced[name] = total
        for reason in DROP_REASONS:
            name = f"corrections_dropped_{reason}"
            total = self.writer.queue_dropped_bytes if reason == "queue" else c.dropped[reason]
            if total != self._synced.get(name, 0):
                # frames of types the receiver does not decode (a caster's 1033 every 30 s,
                # MSM) are expected, not a fault: a count; the rest are errors
                tally = health.count if reason == "type" else health.error
                tally(name, total - self._synced.get(name, 0))
                self._synced[name] = total
        if c.dropped_types:
            health.set("corrections_dropped_types", {str(t): n for t, n in sorted(c.dropped_types.items())})
        age = None if self._last_sample_s is None else clock.monotonic() - self._last_sample_s
        health.set("corrections_age_s", None if age is None else round(age, 2))
        if self.receiver.corrections_refused:
            state = "refused"
        elif not self.writer.attached:
            state = "not_ready"
        elif self.receiver.corrections_unconfirmed and not self._differential_seen:
            state = "unconfirmed"
        elif age is None or age > self.STALE_S:
            state = "waiting"
        else:
            state = "flowing"
        health.set("corrections_state", state)


class NmeaSource(ReceiverDevice):
    """An NMEA receiver: nothing to configure, each epoch one fix."""

    protocol = "nmea"
    kind = "NMEA receiver"

    def __init__(self, service: GnssService):
        super().__init__(service)
        s = service.settings
        self.baudrate = s.baudrate
        self.uere_m = s.nmea_uere_m
        self._date_problem: str | None = None      # said once, until it changes
        self.receiver = NmeaReceiver(s.port, on_fix=self._on_fix,
                                     on_link_error=self.link_failed)

    def _start(self, again: bool) -> None:
        self.receiver.open(self.baudrate)

    def disconnect(self) -> None:
        self.receiver.close()

    def last_rx_ns(self) -> int:
        return self.receiver.last_sentence_host_ns

    def counters(self) -> tuple[dict, dict]:
        st = self.receiver.stats
        counts = {"sentences": st.sentences, "epochs": st.epochs,
                  "ignored_sentences": st.ignored_sentences}
        counts["rollover_corrected"] = st.rollover_corrected
        errors = {"checksum_errors": st.checksum_errors, "parse_errors": st.parse_errors,
                  "incomplete_epochs": st.incomplete_epochs, "rollover_refused": st.rollover_refused,
                  "dropped_logs": self.receiver.dropped_fixes}
        return counts, errors

    def _on_fix(self, fix) -> None:
        self.service.silence.epoch(fix.t_host_ns)
        if fix.date_problem and fix.date_problem != self._date_problem:
            self.service.log.warning("fixes not valid: %s", fix.date_problem)
        self._date_problem = fix.date_problem

        def build():
            sample = fix_from_nmea(fix, self.service.unit, 0, self.uere_m)
            if sample is None:
                self.service.health.count("nofix_epochs")
                return []
            return [sample]
        self.service.publish_all(build)


class GnssService(Service):
    """One GNSS receiver (NovAtel OEM4 binary or NMEA) publishing viena.gnss.fix/1."""

    name = "gnss"
    default_unit = "gnss0"
    unit: str                       # never None: the default_unit stands in for a missing --unit
    settings_class = GnssSettings
    description = USAGE

    def __init__(self, args):
        super().__init__(args)
        s = self.settings
        source = f"{getattr(args, 'config', None) or 'flags'} [gnss]"
        if not s.port:
            raise ConfigError(f"{source}: no receiver port: give --port URL or the 'port' setting")
        if s.protocol == "novatel" and not {"BESTXYZ", "BESTPOS"} & set(s.logs):
            raise ConfigError(f"{source}: setting 'logs' needs BESTXYZ or BESTPOS to make fixes")
        for name in ("period_s", "command_timeout_s", "silence_timeout_s", "reconnect_max_s"):
            if not getattr(s, name) > 0:
                raise ConfigError(f"{source}: setting '{name}' must be positive")
        if not s.silence_epochs >= 0:
            raise ConfigError(f"{source}: setting 'silence_epochs' must not be negative")
        if s.corrections:
            if s.protocol != "novatel":
                raise ConfigError(f"{source}: setting 'corrections' is for NovAtel receivers (protocol novatel)")
            if not 2 <= s.dgps_timeout_s <= 1000:
                raise ConfigError(f"{source}: setting 'dgps_timeout_s' must be 2-1000 (DGPSTIMEOUT)")
            why = source_id_error(DgpsType[s.corrections], s.corrections_source_id)
            if why:
                raise ConfigError(f"{source}: setting 'corrections_source_id': {why}")
            if s.corrections_baudrate < 0:
                raise ConfigError(f"{source}: setting 'corrections_baudrate' must not be negative")
            if not s.corrections_port and s.send_break == "off":
                raise ConfigError(
                    f"{source}: corrections on the logs' port with send_break = off would strand the receiver "
                    f"(the port takes no commands until a break): use a serial URL with send_break auto or on, "
                    f"or a corrections_port")
        self._seq = itertools.count(1)
        self.source: ReceiverDevice | None = None
        self.supervisor: DeviceSupervisor | None = None
        self.silence = SilenceWatch(s.silence_timeout_s, epochs=s.silence_epochs or None)

    # -- life ------------------------------------------------------------------------
    def start(self) -> None:
        s = self.settings
        self.fix_pub = self.publisher(topics.GNSS_FIX, unit=self.unit)
        self.source = (NmeaSource if s.protocol == "nmea" else NovatelSource)(self)
        self.health.set("protocol", self.source.protocol)
        if isinstance(self.source, NovatelSource) and self.source.corrections is not None:
            if not s.corrections_port and urlsplit(s.port).scheme in BREAKLESS_SCHEMES:
                self.log.warning("corrections on the logs' port of %s: no break can be sent there, so the port's "
                                 "reset relies on the far end treating a new connection as a break "
                                 "(the NovAtel twin does, ser2net does not)", s.port)
            self.source.corrections.start()
            self.declare_subscriber(self.keys.of(topics.GNSS_CORRECTIONS), self.source.corrections.on_sample)
        self.supervisor = DeviceSupervisor(
            self.source, self.health, self.silence, url=s.port,
            backoff=Backoff(FIRST_RETRY_S, s.reconnect_max_s), tick_s=WATCH_PERIOD_S,
            stopping=self.stopping).start()

    def stop(self) -> None:
        """The supervisor says UNLOGALL and closes (or gives up if the receiver is stuck)."""
        self.stopping.set()
        if self.supervisor is not None:
            self.supervisor.stop()
        if isinstance(self.source, NovatelSource) and self.source.corrections is not None:
            self.source.corrections.stop()

    # -- samples ---------------------------------------------------------------------
    def publish_all(self, build) -> None:
        """Build fixes (in the driver's reader thread) and publish them, numbered."""
        try:
            samples = build()
        except Exception as exc:  # noqa: BLE001 - one bad epoch must not stop the stream
            self.health.error("bad_fix")
            self.log.warning("could not build a fix: %r", exc)
            return
        for sample in samples:
            sample["seq"] = next(self._seq)
            if self.fix_pub.put(sample):
                self.health.count("fixes")
                self.health.mark_sample()
                self.health.set("pos_status", sample["pos_status"])
                self.health.set("pos_type", sample["pos_type"])
                kind = solution_kind(sample["pos_type"])
                self.health.set("solution_kind", kind)
                if isinstance(self.source, NovatelSource) and self.source.corrections is not None:
                    self.source.corrections.fix_kind(kind)
                self.health.set("diff_age_s", sample.get("diff_age_s"))
                self.health.set("base_id", sample.get("base_id"))
                self.health.set("sats_used", sample["sats_used"])


def main(argv=None) -> int:
    return run_service(GnssService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
