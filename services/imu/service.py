"""viena-imu: one Razor unit on zenoh. Reads the driver, calibrates, publishes; no bytes here.

    viena-imu --unit razor0 --port /dev/ttyUSB0 [--firmware viena|razor-ahrs]

Publishes viena.imu.sample/1 on viena/<car>/imu/<unit>/sample at the device rate. The
device may vanish, stall or send garbage: the service reports it in its health, reopens
the port with a backoff of at most `reconnect_max_s`, and goes on.
"""
from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import serial

from viena.common.errors import ConfigError
from viena.common.service import Service, run_service
from viena.services.imu.calibration import DEFAULT_FILE, FIRMWARES, SampleCalibrator, load_calibration
from viena.services.imu.driver import DRIVERS, RazorAhrs, SerialImu
from viena.services.imu.glitch import MagGlitchFilter
from viena.services.imu.sample import SAMPLE, SampleBuilder

#: decoder counters reported as health errors, by their name in the driver's stats
_ERROR_STATS = ("crc_errors", "resyncs", "bytes_skipped", "bad_frames")
#: how often decoder counters reach the health, board text the log, and the calibration
#: file's time stamp is looked at
CHORES_PERIOD_S = 0.25


class ImuService(Service):
    """Razor 9DOF IMU: calibrated body-frame samples in SI, plus the raw frame values."""

    name = "imu"
    default_unit = "razor0"
    settings_defaults = {
        "port": "",                   # pyserial URL: /dev/ttyUSB0, socket://127.0.0.1:PORT, ...
        "firmware": "viena",          # viena (the car's, 52-byte frames) or razor-ahrs (stock)
        "baudrate": 0,                # 0: the firmware's own (500000 or 57600)
        "calibration": str(DEFAULT_FILE),   # TOML file with a table per unit
        "ahrs_output": "binary",      # razor-ahrs only: binary (#oscb) or text (#osct)
        "mag_field_nT": 43810.0,      # |Earth field| here (Lisbon), for the glitch filter
        "reconnect_max_s": 1.0,       # longest wait between attempts to reopen the port
        "stall_s": 10.0,              # no frame for this long on an open port: reopen it
    }

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("IMU")
        g.add_argument("--port", metavar="URL", help="the unit's serial port as a pyserial URL")
        g.add_argument("--firmware", choices=FIRMWARES, help="what the board runs (default viena)")
        g.add_argument("--baudrate", type=int, metavar="BAUD", help="override the firmware's baud rate")
        g.add_argument("--calibration", metavar="FILE",
                       help=f"calibration TOML (default {DEFAULT_FILE}); a missing file or unit "
                            f"means the seed's values")

    def start(self) -> None:
        s = self.settings
        if not s["port"]:
            raise ConfigError(f"imu {self.unit}: no port: give --port URL or 'port' in [imu.{self.unit}]")
        if s["firmware"] not in FIRMWARES:
            raise ConfigError(f"imu {self.unit}: firmware must be one of {', '.join(FIRMWARES)}")
        self._calibration_path = Path(s["calibration"]) if s["calibration"] else None
        self._calibration_stamp = self._file_stamp()
        calibration, how = load_calibration(self._calibration_path, self.unit, s["firmware"])
        self.log.info("%s", how)
        self.builder = SampleBuilder(self.unit, s["firmware"], SampleCalibrator(calibration),
                                     MagGlitchFilter(field_T=s["mag_field_nT"] * 1e-9))
        self.driver = self._make_driver()
        self.sample_pub = self.publisher(self.keys.key("imu", self.unit, "sample"), SAMPLE)
        self.health.set("connected", False)
        self.health.set("port", s["port"])
        self.health.set("firmware", s["firmware"])
        self.health.set("calibration", calibration.source)
        self._reported = {name: 0 for name in _ERROR_STATS}
        self._last_seq: int | None = None
        self._text_seen = 0
        self._thread = threading.Thread(target=self._run, name=f"imu-{self.unit}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.stopping.set()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.join(timeout=0.6)
        driver = getattr(self, "driver", None)
        if driver is not None:
            driver.close()          # wakes a reader stuck in a synch wait or a slow read
        if thread is not None:
            thread.join(timeout=0.6)

    def _make_driver(self) -> SerialImu:
        s = self.settings
        cls = DRIVERS[s["firmware"]]
        kwargs = {"output": s["ahrs_output"]} if cls is RazorAhrs else {}
        return cls(s["port"], s["baudrate"] or None, timeout=0.1, **kwargs)

    # -- the reader thread ---------------------------------------------------------------------
    def _run(self) -> None:
        backoff_max = max(0.05, self.settings["reconnect_max_s"])
        backoff = 0.05
        opened_before = False
        failing_since = None
        while not self.stopping.is_set():
            try:
                self.driver.open()
            except (serial.SerialException, OSError) as exc:
                if failing_since is None:
                    failing_since = time.monotonic()
                    self.log.warning("cannot open %s: %s (retrying)", self.settings["port"], exc)
                self.health.error("open_failures")
                self.stopping.wait(backoff)
                backoff = min(backoff * 2, backoff_max)
                continue
            if opened_before:
                self.health.count("reconnects")
            after = f" after {time.monotonic() - failing_since:.1f} s" if failing_since else ""
            self.log.info("%s %s on %s%s", "reopened" if opened_before else "opened",
                          self.driver.firmware, self.settings["port"], after)
            opened_before, failing_since, backoff = True, None, 0.05
            self.health.set("connected", True)
            try:
                self._read_until_lost()
            except (serial.SerialException, OSError) as exc:
                if not self.stopping.is_set():
                    self.log.warning("lost %s: %s", self.settings["port"], exc)
                    self.health.error("disconnects")
                    failing_since = time.monotonic()
            except Exception:                  # a bug must not end the service: log, reopen
                self.log.exception("reader failed; reopening %s", self.settings["port"])
                self.health.error("internal_errors")
                self.stopping.wait(backoff_max)
            finally:
                self.driver.close()
                self.builder.mag_filter.reset()
                self.health.set("connected", False)

    def _read_until_lost(self) -> None:
        stall_s = self.settings["stall_s"]
        last_frame = next_chores = time.monotonic()
        while not self.stopping.is_set():
            reading = self.driver.read(timeout=0.2)
            now = time.monotonic()
            if reading is not None:
                last_frame = now
                self._publish(reading)
            elif now - last_frame > stall_s:
                self.health.error("stalls")
                raise serial.SerialException(f"no frame for {stall_s:.0f} s")
            if now >= next_chores:            # a few times a second, not per frame
                next_chores = now + CHORES_PERIOD_S
                self._report_stats()
                self._log_board_text()
                self._reload_calibration_if_changed()

    def _publish(self, reading) -> None:
        if self._last_seq is not None and reading.seq > self._last_seq + 1:
            self.health.error("lost_frames", reading.seq - self._last_seq - 1)
        self._last_seq = reading.seq
        sample = self.builder.build(reading)
        if sample["mag_T"] is None:
            self.health.error("mag_glitches")
        if self.sample_pub.put(sample):
            self.health.count("samples")
            self.health.mark_sample()

    # -- calibration file ---------------------------------------------------------------------
    def _file_stamp(self):
        try:
            st = self._calibration_path.stat()
        except (OSError, AttributeError):
            return None
        return st.st_mtime_ns, st.st_size

    def _reload_calibration_if_changed(self) -> None:
        """`viena calibrate imu` rewrites the file: use the new values without a restart.
        A file that does not load keeps the calibration in use."""
        stamp = self._file_stamp()
        if stamp == self._calibration_stamp:
            return
        self._calibration_stamp = stamp
        try:
            calibration, how = load_calibration(self._calibration_path, self.unit, self.settings["firmware"])
        except ConfigError as exc:
            self.log.error("calibration file changed but cannot be used, keeping the current one: %s", exc)
            self.health.error("calibration_errors")
            return
        self.builder.calibrator = SampleCalibrator(calibration)
        self.health.set("calibration", calibration.source)
        self.log.info("reloaded: %s", how)

    def _report_stats(self) -> None:
        stats = self.driver.stats
        for name, reported in self._reported.items():
            value = getattr(stats, name, 0)
            if value > reported:
                self.health.error(name, value - reported)
                self._reported[name] = value

    def _log_board_text(self) -> None:
        """The board's boot text, once per line, in the log."""
        text = getattr(self.driver, "board_text", None)
        lines = getattr(self.driver.stats, "text_lines", 0)
        if text is not None and lines > self._text_seen:
            for line in list(text)[-min(lines - self._text_seen, len(text)):]:
                self.log.info("board says: %s", line)
            self._text_seen = lines


def main(argv: list[str] | None = None) -> int:
    return run_service(ImuService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
