"""`viena-gnss`: one GNSS receiver's fixes on viena/<car>/gnss/<unit>/fix.

    viena-gnss --unit gnss0 --port /dev/ttyUSB0                  # NovAtel OEM4, binary
    viena-gnss --unit gps0 --port socket://127.0.0.1:5002 --protocol nmea

The driver does the bytes; this process configures the receiver (the car's start-up
sequence), turns its logs into samples, and keeps going whatever the device does: a port
that fails or a receiver that goes silent is reported in health, closed, and reopened
with a backoff capped at ``reconnect_max_s``, so data flows again within a second of the
device coming back. Health counts frames, CRC errors, resyncs, command failures,
reconnects and the age of the last fix.
"""
from __future__ import annotations

import itertools
import threading
import time
from dataclasses import replace

import serial

from viena.common.errors import ConfigError
from viena.common.service import Service, run_service

from .driver.nmea import NmeaReceiver
from .driver.novatel import (
    CommandError, CommandTimeout, Dynamics, LogRequest, MessageId, NovatelReceiver,
    SbasKeyword, SbasSystem, StartupConfig, Trigger,
)
from .fix import FIX, NovatelFixBuilder, fix_from_nmea

USAGE = __doc__
LOGGED = ("BESTXYZ", "BESTPOS", "BESTVEL")
CONNECT_ERRORS = (CommandError, CommandTimeout, serial.SerialException, OSError, ValueError)
WATCH_PERIOD_S = 0.1
FIRST_RETRY_S = 0.05


def _choice(settings: dict, name: str, allowed, source: str) -> str:
    value = settings[name]
    if value not in allowed:
        raise ConfigError(f"{source}: setting '{name}' must be one of {sorted(allowed)}, "
                          f"got {value!r}")
    return value


class NovatelSource:
    """A NovAtel OEM4 receiver: start-up sequence, BESTXYZ (or BESTPOS+BESTVEL) to fixes."""

    protocol = "novatel"

    def __init__(self, service: "GnssService"):
        s = service.settings
        self.service = service
        self.receiver = NovatelReceiver(s["port"], command_timeout=s["command_timeout_s"],
                                        on_log=self._on_log,
                                        on_link_error=service.link_failed)
        send_break = {"auto": None, "on": True, "off": False}[s["send_break"]]
        logs = tuple(LogRequest(MessageId[name], Trigger[s["trigger"]], s["period_s"])
                     for name in s["logs"])
        self.config = StartupConfig(
            initial_baud=s["initial_baud"], baud=s["baud"], send_break=send_break,
            dynamics=Dynamics[s["dynamics"]],
            sbas=SbasKeyword[s["sbas"]] if s["sbas"] else None,
            sbas_system=SbasSystem[s["sbas_system"]], logs=logs)
        self.builder = NovatelFixBuilder(service.unit, join_bestvel="BESTVEL" in s["logs"])

    def connect(self, again: bool = False) -> None:
        """The start-up sequence. Coming back after a lost link, first try the receiver
        as it most likely still is (working rate, no 2 s break), then the whole sequence."""
        if again and self.config.send_break is not False:
            quick = replace(self.config, send_break=False, initial_baud=self.config.baud)
            try:
                self.receiver.startup(quick)
                return
            except CommandTimeout:
                self.receiver.close()
        self.receiver.startup(self.config)

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
        self.service.publish_all(lambda: self.builder.add(message))


class NmeaSource:
    """An NMEA receiver: nothing to configure, each epoch one fix."""

    protocol = "nmea"

    def __init__(self, service: "GnssService"):
        s = service.settings
        self.service = service
        self.baud = s["baud"]
        self.uere_m = s["nmea_uere_m"]
        self.receiver = NmeaReceiver(s["port"], on_fix=self._on_fix,
                                     on_link_error=service.link_failed)

    def connect(self, again: bool = False) -> None:
        self.receiver.open(self.baud)

    def disconnect(self) -> None:
        self.receiver.close()

    shutdown = disconnect

    def last_rx_ns(self) -> int:
        return self.receiver.last_sentence_host_ns

    def counters(self) -> tuple[dict, dict]:
        st = self.receiver.stats
        counts = {"sentences": st.sentences, "epochs": st.epochs,
                  "ignored_sentences": st.ignored_sentences}
        errors = {"checksum_errors": st.checksum_errors, "parse_errors": st.parse_errors,
                  "incomplete_epochs": st.incomplete_epochs,
                  "dropped_logs": self.receiver.dropped_fixes}
        return counts, errors

    def _on_fix(self, fix) -> None:
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
    settings_defaults = {
        "port": "",                     # pyserial URL: /dev/ttyUSB0, socket://h:p, rfc2217://
        "protocol": "novatel",          # novatel | nmea
        "baud": 115200,                 # working rate (NovAtel: set by COM; NMEA: opened at)
        "initial_baud": 9600,           # NovAtel factory rate, what a break restores
        "send_break": "auto",           # auto (not on socket://) | on | off
        "logs": ["BESTXYZ"],            # NovAtel logs: BESTXYZ, or BESTPOS and BESTVEL
        "trigger": "ONTIME",
        "period_s": 0.05,               # 20 Hz
        "dynamics": "AIR",              # AIR | LAND | FOOT (the manual advises AIR)
        "sbas": "ENABLE",               # ENABLE | DISABLE | "" (leave the receiver's)
        "sbas_system": "AUTO",          # NONE AUTO ANY WAAS EGNOS MSAS
        "command_timeout_s": 1.0,
        "silence_timeout_s": 1.0,       # no bytes for this long: reconnect
        "reconnect_max_s": 0.5,         # backoff cap between attempts
        "nmea_uere_m": 3.0,             # NMEA sigmas = DOP x this user range error
    }
    description = USAGE

    @classmethod
    def add_arguments(cls, parser) -> None:
        g = parser.add_argument_group("receiver")
        g.add_argument("--port", dest="port", metavar="URL",
                       help="pyserial URL of the receiver: /dev/ttyUSB0, socket://HOST:PORT, "
                            "rfc2217://HOST:PORT")
        g.add_argument("--protocol", dest="protocol", choices=("novatel", "nmea"),
                       help="NovAtel OEM4 binary (default) or NMEA 0183")
        g.add_argument("--baud", dest="baud", type=int, help="working baud rate")

    def __init__(self, args):
        super().__init__(args)
        s = self.settings
        source = f"{getattr(args, 'config', None) or 'flags'} [gnss]"
        if not s["port"]:
            raise ConfigError(f"{source}: no receiver port: give --port URL or the 'port' setting")
        _choice(s, "protocol", ("novatel", "nmea"), source)
        _choice(s, "send_break", ("auto", "on", "off"), source)
        _choice(s, "trigger", Trigger.__members__, source)
        _choice(s, "dynamics", Dynamics.__members__, source)
        _choice(s, "sbas", ("", *SbasKeyword.__members__), source)
        _choice(s, "sbas_system", SbasSystem.__members__, source)
        for log in s["logs"]:
            if log not in LOGGED:
                raise ConfigError(f"{source}: setting 'logs' may hold {list(LOGGED)}, got {log!r}")
        if s["protocol"] == "novatel" and not {"BESTXYZ", "BESTPOS"} & set(s["logs"]):
            raise ConfigError(f"{source}: setting 'logs' needs BESTXYZ or BESTPOS to make fixes")
        for name in ("period_s", "command_timeout_s", "silence_timeout_s", "reconnect_max_s"):
            if not s[name] > 0:
                raise ConfigError(f"{source}: setting '{name}' must be positive")
        self._seq = itertools.count(1)
        self._link_error = threading.Event()
        self._link_error_text = ""
        self._pushed: dict[str, int] = {}
        self._thread: threading.Thread | None = None
        self.source = None

    # -- life ------------------------------------------------------------------------
    def start(self) -> None:
        self.fix_pub = self.publisher(self.keys.key("gnss", self.unit, "fix"), FIX)
        self.source = (NmeaSource if self.settings["protocol"] == "nmea" else NovatelSource)(self)
        self.health.set("port", self.settings["port"])
        self.health.set("protocol", self.source.protocol)
        self.health.set("connected", False)
        counts, errors = self.source.counters()       # show every counter, even at zero
        for name in counts:
            self.health.count(name, 0)
        for name in (*errors, "connect_failures", "reconnects", "silences", "port_failures"):
            self.health.error(name, 0)
        self._thread = threading.Thread(target=self._supervise, name="gnss-supervisor",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Let the supervisor say UNLOGALL and close; if it is stuck waiting for an
        answer, close the port under it so it gives up at once."""
        self.stopping.set()
        if self._thread is None:
            return
        self._thread.join(timeout=0.7)
        if self._thread.is_alive():
            self.source.disconnect()
            self._thread.join(timeout=0.8)

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

    # -- connection ------------------------------------------------------------------
    def link_failed(self, exc: Exception) -> None:
        """The driver's port failed (called from its reader thread)."""
        self._link_error_text = str(exc) or type(exc).__name__
        self._link_error.set()

    def _supervise(self) -> None:
        url = self.settings["port"]
        delay, attempts, connected_once = 0.0, 0, False
        while not self.stopping.is_set():
            self._link_error.clear()
            try:
                self.source.connect(again=connected_once)
            except CONNECT_ERRORS as exc:
                self.source.disconnect()
                self._push_counters()
                if self.stopping.is_set():
                    break
                self.health.error("connect_failures")
                self.health.set("last_error", str(exc))
                log = self.log.warning if attempts == 0 else self.log.debug
                log("%s: cannot start the receiver: %s (retrying)", url, exc)
                attempts += 1
                delay = min(max(2 * delay, FIRST_RETRY_S), self.settings["reconnect_max_s"])
                self.stopping.wait(delay)
                continue
            if connected_once:
                self.health.error("reconnects")
                self.log.info("%s: receiving again (after %d failed attempts)", url, attempts)
            else:
                self.log.info("%s: receiving (%s)", url, self.source.protocol)
            connected_once, attempts, delay = True, 0, 0.0
            self.health.set("connected", True)
            reason = self._watch()
            self.health.set("connected", False)
            if reason is None:
                break
            self.health.set("last_error", reason)
            self.log.warning("%s: %s: reconnecting", url, reason)
            self.source.disconnect()
        self._push_counters()
        try:
            self.source.shutdown()
        except Exception as exc:  # noqa: BLE001 - closing is best effort
            self.log.debug("shutdown: %s", exc)

    def _watch(self) -> str | None:
        """Wait while the receiver talks; the reason it stopped, None when stopping."""
        silence_ns = int(self.settings["silence_timeout_s"] * 1e9)
        since = time.time_ns()
        while not self.stopping.wait(WATCH_PERIOD_S):
            self._push_counters()
            if self._link_error.is_set():
                self.health.error("port_failures")
                return f"port failed ({self._link_error_text})"
            now = time.time_ns()
            quiet_ns = now - max(self.source.last_rx_ns(), since)
            if quiet_ns > silence_ns:
                self.health.error("silences")
                return f"silent for {quiet_ns / 1e9:.1f} s"
        return None

    def _push_counters(self) -> None:
        """Move the driver's running totals into health (as increments, so rates work)."""
        counts, errors = self.source.counters()
        for table, bump in ((counts, self.health.count), (errors, self.health.error)):
            for name, total in table.items():
                delta = total - self._pushed.get(name, 0)
                if delta:
                    bump(name, delta)
                    self._pushed[name] = total


def main(argv=None) -> int:
    return run_service(GnssService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
