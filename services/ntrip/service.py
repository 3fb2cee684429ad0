"""`viena-ntrip`: RTK/DGPS corrections from an NTRIP caster onto viena/<car>/gnss/corrections.

    viena-ntrip --caster caster.example.org --mountpoint NEAR0 [--ntrip-version 1.0] [--tls]
    viena-ntrip --config compose/pi.toml            # the [ntrip] table

The login comes from a file only its owner can read (`credentials`, default
~/.config/viena/ntrip/<car>.credentials: one line `user:password`), never from the command
line; a file group or others can read is refused at start in one line, as ssh refuses such
a key. The driver (driver/client.py) connects, reads and reconnects as casters allow (never
two attempts less than 10 s apart, then backing off to `retry_max_s`); this process
publishes:

- `gnss/corrections` (viena.gnss.corrections/1, common/samples/corrections.py): each read's whole
  checked RTCM 3 frames (format RTCMV3), or its bytes as they came (RAW), which the GNSS
  services write to their receivers;
- `ntrip/state` (viena.ntrip.state/1, common/samples/ntrip.py): at 1 Hz and at every change, what
  the link does and why it does not stream;
- `ntrip/health`: counters for every kind of bad input (unauthorized, mountpoint_unknown,
  html_answers, connection_refused, garbage_bytes, crc_errors, silences, ...), and
  `link` = "lost ..." (the monitor shows it red) while not streaming for longer than
  `lost_after_s`.

With `gga_interval_s` > 0 the car's position goes upstream as a GGA (a VRS or
nearest-base caster picks its base by it): the newest valid fix on `gnss/*/fix`.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import zenoh

from viena.common import clock
from viena.common.errors import ConfigError, SampleError
from viena.common.samples import topics
from viena.common.samples.corrections import FORMATS, corrections_sample
from viena.common.samples.fix import FIX, solution_kind
from viena.common.schema import unpack
from viena.common.service import Service, run_service
from viena.common.settings import setting
from viena.services.ntrip.driver.caster import CasterAddress
from viena.services.ntrip.driver.client import ClientConfig, NtripClient
from viena.services.ntrip.driver.credentials import CredentialsError, default_path, read_credentials
from viena.services.ntrip.driver.protocol import Position
from viena.services.ntrip.driver.retry import MIN_INTERVAL_S, RetryPolicy
from viena.services.ntrip.driver.rtcm3 import Batch

USAGE = __doc__
STATE_PERIOD_S = 1.0
#: a fix older than this is no position to send upstream
FIX_MAX_AGE_S = 60.0
#: every counter the health shows from the start (so a zero reads as "none yet")
ERROR_KINDS = ("credentials", "unauthorized", "mountpoint_unknown", "html_answers", "not_ntrip",
               "http_errors", "connection_refused", "unreachable", "tls_errors", "dropped", "silences",
               "garbage_bytes", "crc_errors", "internal_errors", "lost")
_FIX_FIELDS = FIX.reader("valid", "lat_deg", "lon_deg", "height_m", "pos_type", "sats_used", "diff_age_s",
                         "base_id", defaults={"pos_type": "SINGLE", "sats_used": 8})


@dataclass(frozen=True)
class NtripSettings:
    """[ntrip]: the caster, the mountpoint, the login file, and how to keep the link."""
    caster: str = setting("", "the caster's host name or address", metavar="HOST")
    port: int = setting(2101, "the caster's TCP port")
    mountpoint: str = setting("", "the mountpoint (`viena ntrip sources HOST` lists them)", metavar="NAME")
    ntrip_version: str = setting("2.0", "NTRIP version (1.0: ICY answers, no chunks, GGA as data)",
                                 choices=("2.0", "1.0"))
    tls: bool = setting(False, "TLS to the caster (NTRIP over TLS; such casters often listen on 443)")
    ca_file: str = setting("", "TLS: the CA that signed the caster's certificate (\"\": the system's CAs)",
                           metavar="FILE")
    credentials: str = setting("", "file holding `user:password`, mode 600 (\"\": "
                                   "~/.config/viena/ntrip/<car>.credentials; \"none\": no login)",
                               metavar="FILE")
    format: str = setting("RTCMV3", "RTCMV3: publish whole CRC-checked RTCM 3 frames; RAW: the bytes as "
                                    "they come (RTCM 2.x, CMR, RTCA casters)", choices=FORMATS)
    gga_interval_s: float = setting(0.0, "send the car's position upstream (GGA) this often; 0: never "
                                         "(a VRS or nearest-base mountpoint needs it)")
    inactivity_s: float = setting(10.0, "no data for this long on an open stream: reconnect")
    connect_timeout_s: float = setting(10.0, "longest wait for the TCP connection and the caster's answer")
    retry_max_s: float = setting(60.0, "longest wait between attempts after failures (never under 10 s apart)")
    lost_after_s: float = setting(30.0, "not streaming for this long: health says the corrections are lost")

    def address(self) -> CasterAddress:
        """Where the caster is and what to ask it (the service and `viena doctor` alike)."""
        return CasterAddress(self.caster, self.port, self.mountpoint, self.ntrip_version, self.tls,
                             str(Path(self.ca_file).expanduser()) if self.ca_file else "")

    def credentials_path(self, car: str) -> Path | None:
        """The login file these settings name (None: the caster wants no login)."""
        if self.credentials.lower() == "none":
            return None
        return Path(self.credentials).expanduser() if self.credentials else default_path(car)


class NtripService(Service):
    """The NTRIP client: corrections in, viena.gnss.corrections/1 out."""

    name = "ntrip"
    settings_class = NtripSettings
    description = USAGE

    def __init__(self, args) -> None:
        super().__init__(args)
        s = self.settings
        where = f"{getattr(args, 'config', None) or 'flags'} [ntrip]"
        if not s.caster:
            raise ConfigError(f"{where}: no caster: give --caster HOST or the 'caster' setting")
        if not s.mountpoint:
            raise ConfigError(f"{where}: no mountpoint: give --mountpoint NAME (`viena ntrip sources "
                              f"{s.caster}` lists them)")
        if not 0 < s.port < 65536:
            raise ConfigError(f"{where}: setting 'port' must be a TCP port, got {s.port}")
        for name in ("inactivity_s", "connect_timeout_s", "lost_after_s"):
            if not getattr(s, name) > 0:
                raise ConfigError(f"{where}: setting '{name}' must be positive")
        if not s.gga_interval_s >= 0:
            raise ConfigError(f"{where}: setting 'gga_interval_s' must not be negative")
        if s.ca_file and not Path(s.ca_file).expanduser().is_file():
            raise ConfigError(f"{where}: ca_file {s.ca_file} is not a file")
        self.credentials_file = self._credentials_file()
        self.address = s.address()
        self._seq = itertools.count(1)
        self._state_seq = itertools.count(1)
        self._changed = clock.Event()
        self._position: Position | None = None
        self._position_at = 0.0
        self._pushed: dict[str, int] = {}
        self._lost_said = False
        self.client: NtripClient | None = None

    def _credentials_file(self) -> str:
        """The login file, checked now so that a bad one stops the start in one line. One
        that is not there yet is waited for (each attempt reads it again, and says so in the
        state): the sim's caster twin writes it as it starts, beside this program."""
        path = self.settings.credentials_path(self.keys.car)
        if path is None:
            return ""
        if not path.exists():
            self.log.warning("credentials file %s is not there (yet): each attempt looks again", path)
            return str(path)
        try:
            read_credentials(path)
        except CredentialsError as exc:
            raise ConfigError(str(exc)) from None
        return str(path)

    # -- life ----------------------------------------------------------------------------------
    def start(self) -> None:
        s = self.settings
        self.corrections_pub = self.publisher(topics.GNSS_CORRECTIONS)
        self.state_pub = self.publisher(topics.NTRIP_STATE)
        self._fixes = None
        if s.gga_interval_s > 0:
            self._fixes = self.declare_subscriber(
                self.keys.of(topics.GNSS_FIX), zenoh.handlers.RingChannel(1))
        for kind in ERROR_KINDS:
            self.health.error(kind, 0)
        self.health.set("caster", self.address.source)
        config = ClientConfig(self.address, self.credentials_file, s.format, s.gga_interval_s,
                              s.inactivity_s, s.connect_timeout_s)
        self.client = NtripClient(config, on_batch=self._publish, on_change=self._changed.set,
                                  position=self._car_position,
                                  policy=RetryPolicy(MIN_INTERVAL_S, s.retry_max_s), log=self.log)
        self._since_streaming = clock.monotonic()
        self.log.info("corrections from %s (NTRIP %s%s, %s%s)", self.address.source, s.ntrip_version,
                      ", TLS" if s.tls else "", s.format,
                      f", GGA every {s.gga_interval_s:g} s" if s.gga_interval_s > 0 else "")
        self.client.start()
        self._state_thread = clock.Thread(target=self._state_loop, name="ntrip-state", daemon=True)
        self._state_thread.start()

    def stop(self) -> None:
        self.stopping.set()
        self._changed.set()
        if self.client is not None:
            self.client.stop()
        thread = getattr(self, "_state_thread", None)
        if thread is not None:
            thread.join(timeout=0.5)

    # -- corrections -----------------------------------------------------------------------------
    def _publish(self, batch: Batch) -> None:
        """One read's frames (or bytes) as one sample (on the client's thread)."""
        sample = corrections_sample(clock.time_ns(), next(self._seq), self.address.source, batch.data,
                                    self.settings.format, batch.types, batch.base_id)
        if self.corrections_pub.put(sample):
            self.health.count("corrections")
            self.health.count("corrections_bytes", len(batch.data))
            self.health.mark_sample()

    # -- the car's position, for the GGA --------------------------------------------------------
    def _car_position(self) -> Position | None:
        """The newest valid fix on the bus (any receiver), if not older than FIX_MAX_AGE_S."""
        sample = self._fixes.try_recv() if self._fixes is not None else None
        if sample is not None:
            try:
                valid, lat, lon, h, pos_type, sats, diff_age, base_id = _FIX_FIELDS(
                    unpack(sample.payload.to_bytes(), "fix"))
            except SampleError:
                self.health.error("bad_fixes")
            else:
                if valid:
                    self._position = Position(lat, lon, h, solution_kind(pos_type), sats or 0, 1.0,
                                              diff_age or 0.0, base_id or "0")
                    self._position_at = clock.monotonic()
        if self._position is None or clock.monotonic() - self._position_at > FIX_MAX_AGE_S:
            return None
        return self._position

    # -- state and health --------------------------------------------------------------------------
    def _state_loop(self) -> None:
        """ntrip/state at 1 Hz and at every change; the client's counters into health."""
        while not self.stopping.is_set():
            self._changed.wait(STATE_PERIOD_S)
            self._changed.clear()
            if self.stopping.is_set():
                break
            self.publish_state()

    def publish_state(self) -> None:
        client = self.client
        if client is None:
            return
        status = client.status()
        self.state_pub.put({"t": clock.time_ns(), "seq": next(self._state_seq), **status})
        self._update_health(status)

    def _update_health(self, status: dict) -> None:
        client, health = self.client, self.health
        assert client is not None
        errors = dict(client.errors)
        if client.framer is not None:
            errors["crc_errors"] = client.framer.crc_errors
        for name, total in errors.items():
            if total > self._pushed.get(name, 0):
                health.error(name, total - self._pushed.get(name, 0))
                self._pushed[name] = total
        now = clock.monotonic()
        for name in ("connected", "state", "why", "base_id"):
            health.set(name, status[name])
        health.set("attempts", status["attempts"])
        if status["state"] == "streaming":
            self._since_streaming, self._lost_said = now, False
            health.set("link", "streaming")
            return
        down_s = now - self._since_streaming
        if down_s > self.settings.lost_after_s:
            health.set("link", f"corrections lost for {down_s:.0f} s: {status['why'] or status['state']}")
            if not self._lost_said:
                self._lost_said = True
                health.error("lost")
                self.log.warning("no corrections for %.0f s: %s", down_s, status["why"] or status["state"])
        else:
            health.set("link", status["state"])


def main(argv=None) -> int:
    return run_service(NtripService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
