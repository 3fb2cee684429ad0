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
"""
from __future__ import annotations

import itertools
from abc import abstractmethod
from dataclasses import dataclass, replace

import serial

from viena.common import clock
from viena.common.errors import ConfigError
from viena.common.service import Service, run_service
from viena.common.settings import setting
from viena.common.silence import SilenceWatch
from viena.common.supervisor import Backoff, Device, DeviceSupervisor
from viena.services.gnss.driver.nmea import NmeaReceiver
from viena.services.gnss.driver.novatel import (
    CommandError,
    CommandTimeout,
    Dynamics,
    LogRequest,
    MessageId,
    NovatelReceiver,
    SbasKeyword,
    SbasSystem,
    StartupConfig,
    Trigger,
    check_sbas,
)
from viena.services.gnss.model.fix import FIX, NovatelFixBuilder, fix_from_nmea

USAGE = __doc__
LOGGED = ("BESTXYZ", "BESTPOS", "BESTVEL")
CONNECT_ERRORS = (CommandError, CommandTimeout, serial.SerialException, OSError, ValueError)
WATCH_PERIOD_S = 0.1
#: how long after a start-up the receiver's RXCONFIG may take to confirm SBASCONTROL
SBAS_CONFIRM_S = 5.0
FIRST_RETRY_S = 0.05


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
        self.config = StartupConfig(
            initial_baud=s.initial_baudrate, baud=s.baudrate, send_break=send_break,
            dynamics=Dynamics[s.dynamics], sbas=SbasKeyword[s.sbas] if s.sbas else None,
            sbas_system=SbasSystem[s.sbas_system], sbas_enable_value=s.sbas_enable_value,
            logs=logs, read_config=True)
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
        if again and self.config.send_break is not False:
            quick = replace(self.config, send_break=False, initial_baud=self.config.baud)
            try:
                self.receiver.startup(quick)
                return
            except CommandTimeout:
                self.receiver.close()
        self.receiver.startup(self.config)

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
        self.receiver.close()

    def shutdown(self) -> None:
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
        self._seq = itertools.count(1)
        self.source: ReceiverDevice | None = None
        self.supervisor: DeviceSupervisor | None = None
        self.silence = SilenceWatch(s.silence_timeout_s, epochs=s.silence_epochs or None)

    # -- life ------------------------------------------------------------------------
    def start(self) -> None:
        s = self.settings
        self.fix_pub = self.publisher(self.keys.key("gnss", self.unit, "fix"), FIX)
        self.source = (NmeaSource if s.protocol == "nmea" else NovatelSource)(self)
        self.health.set("protocol", self.source.protocol)
        self.supervisor = DeviceSupervisor(
            self.source, self.health, self.silence, url=s.port,
            backoff=Backoff(FIRST_RETRY_S, s.reconnect_max_s), tick_s=WATCH_PERIOD_S,
            stopping=self.stopping).start()

    def stop(self) -> None:
        """The supervisor says UNLOGALL and closes (or gives up if the receiver is stuck)."""
        self.stopping.set()
        if self.supervisor is not None:
            self.supervisor.stop()

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
                self.health.set("sats_used", sample["sats_used"])


def main(argv=None) -> int:
    return run_service(GnssService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
