"""viena-imu: one Razor unit on zenoh. Reads the driver, calibrates, publishes; no bytes here.

    viena-imu --unit razor0 --port /dev/ttyUSB0 [--firmware viena|razor-ahrs]

Publishes viena.imu.sample/1 on viena/<car>/imu/<unit>/sample at the device rate. The
device may vanish, stall or send garbage: the device supervisor (common/supervisor.py)
reports it in the health, reopens the port with a backoff of at most `reconnect_max_s`,
and goes on.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from viena.common import clock
from viena.common.errors import ConfigError
from viena.common.samples.topics import IMU_SAMPLE
from viena.common.service import Service, run_service
from viena.common.settings import setting
from viena.common.silence import SilenceWatch
from viena.common.supervisor import Backoff, Device, DeviceSupervisor
from viena.services.imu.calibration_file import DEFAULT_FILE, load_calibration
from viena.services.imu.driver import DRIVERS, RazorAhrs, SerialImu
from viena.services.imu.model.calibration import FIRMWARES, SampleCalibrator
from viena.services.imu.model.glitch import MagGlitchFilter
from viena.services.imu.model.sample_builder import SampleBuilder

#: decoder counters reported as health errors, by their name in the driver's stats
#: (out_of_range and unconfirmed: candidate frames refused although their CRC checked)
_ERROR_STATS = ("crc_errors", "out_of_range", "unconfirmed", "resyncs", "bytes_skipped",
                "bad_frames")
#: how often decoder counters reach the health, board text the log, and the calibration
#: file's time stamp is looked at
CHORES_PERIOD_S = 0.25
FIRST_RETRY_S = 0.05


class RazorDevice(Device):
    """The Razor driver under the supervisor. Its reading is pulled, so `serve` reads and
    publishes the frames of one period in the supervisor's thread, then does the chores."""

    kind = "Razor IMU"

    def __init__(self, service: ImuService, driver: SerialImu):
        self.service, self.driver = service, driver

    def connect(self, again: bool) -> None:
        self.driver.open()

    def serve(self, timeout_s: float) -> None:
        deadline = clock.monotonic() + timeout_s
        while (left_s := deadline - clock.monotonic()) > 0:
            reading = self.driver.read(timeout=left_s)
            if reading is None:
                break
            self.service.silence.heard(reading.t_host_ns)
            self.service.publish(reading)
        self.service.chores()

    def disconnect(self) -> None:
        self.driver.close()
        self.service.builder.mag_filter.reset()

    def counters(self) -> tuple[dict, dict]:
        stats = self.driver.stats
        return {}, {name: getattr(stats, name, 0) for name in _ERROR_STATS}


@dataclass(frozen=True)
class ImuSettings:
    """[imu] and [imu.<unit>]: one Razor board, its calibration file, how it is watched."""
    port: str = setting("", "the unit's serial port as a pyserial URL: /dev/ttyUSB0, "
                            "socket://HOST:PORT, ...", metavar="URL")
    firmware: str = setting("viena", "what the board runs: viena (the car's, 52-byte frames) "
                                     "or razor-ahrs (stock)", choices=FIRMWARES)
    baudrate: int = setting(0, "the board's baud rate; 0: the firmware's own (500000 or 57600)")
    calibration: str = setting(str(DEFAULT_FILE), "calibration TOML with a table per unit; a "
                               "missing file or unit means the default calibration, "
                               "docs/sensors.md#default-calibration (\"\": none)",
                               metavar="FILE", shown="$VIENA_CONFIG_DIR/imu_calibration.toml, "
                               "else ~/.config/viena/imu_calibration.toml")
    ahrs_output: str = setting("binary", "razor-ahrs only: binary (#oscb) or text (#osct) frames",
                               choices=("binary", "text"))
    mag_field_nT: float = setting(43810.0, "the Earth's field here (Lisbon), for the glitch filter")
    reconnect_max_s: float = setting(1.0, "longest wait between attempts to reopen the port")
    stall_s: float = setting(10.0, "no frame for this long on an open port: reopen it")


class ImuService(Service):
    """Razor 9DOF IMU: calibrated body-frame samples in SI, plus the raw frame values."""

    name = "imu"
    default_unit = "razor0"
    #: never None: default_unit names one when --unit does not
    unit: str
    settings_class = ImuSettings

    def start(self) -> None:
        s = self.settings
        if not s.port:
            raise ConfigError(f"imu {self.unit}: no port: give --port URL or 'port' in [imu.{self.unit}]")
        self._calibration_path = Path(s.calibration) if s.calibration else None
        self._calibration_stamp = self._file_stamp()
        calibration, how = load_calibration(self._calibration_path, self.unit, s.firmware)
        self.log.info("%s", how)
        self.builder = SampleBuilder(self.unit, s.firmware, SampleCalibrator(calibration),
                                     MagGlitchFilter(field_T=s.mag_field_nT * 1e-9))
        self.driver = self._make_driver()
        self.sample_pub = self.publisher(IMU_SAMPLE, unit=self.unit)
        self.health.set("firmware", s.firmware)
        self.health.set("calibration", calibration.source)
        self._last_seq: int | None = None
        self._text_seen = 0
        self.silence = SilenceWatch(s.stall_s)
        self.supervisor = DeviceSupervisor(
            RazorDevice(self, self.driver), self.health, self.silence, url=s.port,
            backoff=Backoff(FIRST_RETRY_S, max(FIRST_RETRY_S, s.reconnect_max_s)),
            tick_s=CHORES_PERIOD_S, stopping=self.stopping).start()

    def stop(self) -> None:
        self.stopping.set()
        supervisor = getattr(self, "supervisor", None)
        if supervisor is not None:
            supervisor.stop()

    def _make_driver(self) -> SerialImu:
        s = self.settings
        cls = DRIVERS[s.firmware]
        kwargs = {"output": s.ahrs_output} if cls is RazorAhrs else {}
        return cls(s.port, s.baudrate or None, timeout=0.1, **kwargs)

    # -- what the device hands over ---------------------------------------------------------
    def publish(self, reading) -> None:
        if self._last_seq is not None and reading.seq > self._last_seq + 1:
            self.health.error("lost_frames", reading.seq - self._last_seq - 1)
        self._last_seq = reading.seq
        sample = self.builder.build(reading)
        if sample["mag_T"] is None:
            self.health.error("mag_glitches")
        if self.sample_pub.put(sample):
            self.health.count("samples")
            self.health.mark_sample()

    def chores(self) -> None:
        """A few times a second, not per frame."""
        self._log_board_text()
        self._reload_calibration_if_changed()

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
            calibration, how = load_calibration(self._calibration_path, self.unit, self.settings.firmware)
        except ConfigError as exc:
            self.log.error("calibration file changed but cannot be used, keeping the current one: %s", exc)
            self.health.error("calibration_errors")
            return
        self.builder.calibrator = SampleCalibrator(calibration)
        self.health.set("calibration", calibration.source)
        self.log.info("reloaded: %s", how)

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
