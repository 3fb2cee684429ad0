"""python -m viena.services.ntrip.simulator: an NTRIP caster twin with one base station.

    python -m viena.services.ntrip.simulator --port 2101 --mountpoint VIENA0 --baseline-m 2000 \\
        --bearing-deg 45 --credentials ~/.config/viena/ntrip/elettra.credentials
    python -m viena.services.ntrip.simulator --config compose/sim.toml     # its [caster] table

It prints `READY ntrip://HOST:PORT/MOUNTPOINT` once it listens and serves until SIGTERM or
Ctrl-C. The base stands `--baseline-m` from `--origin` (default: the [sim] origin of the
--config file, else the IST campus) at `--bearing-deg`. `--credentials FILE`: the login it
asks for, read from FILE, or (when FILE does not exist) made there with a random password
for `--user` (mode 0600); without it, the caster asks for no login. The password is never
printed or logged.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from dataclasses import dataclass

from viena.common.config import load_toml
from viena.common.errors import ConfigError
from viena.common.log import setup_logging
from viena.common.settings import load, setting
from viena.common.signals import stop_on_signals
from viena.services.sim.model.truth import IST_ORIGIN

from .caster import VERSIONS, CasterTwin, Mountpoint
from .credentials import CredentialsError, credentials_for_caster
from .schedule import MESSAGE_SETS

log = logging.getLogger("viena.ntrip.caster")


@dataclass(frozen=True)
class CasterSettings:
    """[caster]: the NTRIP caster twin and the base station behind its mountpoint."""
    host: str = setting("127.0.0.1", "where the caster listens")
    port: int = setting(2101, "TCP port (0: any free one)")
    mountpoint: str = setting("VIENA0", "the mountpoint's name")
    messages: str = setting("rtk", "what the base sends: rtk = 1004(1),1005(10),1033(30); l1 = 1002 "
                            "instead of 1004; msm = 1074(1),1084(1),1006(10),1033(30)", choices=MESSAGE_SETS)
    origin: tuple[float, ...] = setting((), "where the baseline starts, [lat_deg, lon_deg, height_m]; "
                                        "empty: the [sim] origin of the same file, else the IST campus")
    baseline_m: float = setting(0.0, "the base's distance from the origin, along the ellipsoid")
    bearing_deg: float = setting(0.0, "the baseline's bearing, clockwise from north")
    station_id: int = setting(0, "the reference station id (DF003, 0 to 4095)")
    seed: int = setting(0, "the base's measurement noise and ambiguities")
    vrs: bool = setting(False, "a VRS-like mountpoint: nothing until the rover's GGA, then a base at the rover")
    latency_s: float = setting(0.2, "from an epoch to its frames leaving the caster")
    versions: tuple[str, ...] = setting(VERSIONS, "the NTRIP versions it speaks", choices=VERSIONS)
    credentials: str = setting("", "the login file (one line user:password), made with a random password "
                               "when missing; empty: no login asked")
    user: str = setting("viena", "the user a new credentials file is made for")
    tls_cert: str = setting("", "TLS certificate (PEM); with tls_key, the caster speaks TLS")
    tls_key: str = setting("", "TLS private key (PEM)")
    icy_headers: bool = setting(False, "NTRIP 1.0: Server and Date headers after ICY 200 OK")
    drop_every_s: float = setting(0.0, "fault: drop each client this long after its stream began (0: never)")
    garbage_every_s: float = setting(0.0, "fault: bytes that are no RTCM between frames this often (0: never)")
    flood_bytes_per_s: float = setting(0.0, "fault: extra observables frames at this many bytes a second")


def _triple(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        values = []
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"LAT,LON,H: three numbers, not {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m viena.services.ntrip.simulator", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="FILE", help="a TOML file: its [caster] table (and [sim] origin)")
    p.add_argument("--host")
    p.add_argument("--port", type=int, help="TCP port (0: any free one; default 2101)")
    p.add_argument("--mountpoint", metavar="NAME")
    p.add_argument("--messages", choices=sorted(MESSAGE_SETS))
    p.add_argument("--origin", type=_triple, metavar="LAT,LON,H")
    p.add_argument("--baseline-m", type=float, dest="baseline_m", metavar="M")
    p.add_argument("--bearing-deg", type=float, dest="bearing_deg", metavar="B")
    p.add_argument("--station-id", type=int, dest="station_id")
    p.add_argument("--seed", type=int)
    p.add_argument("--vrs", action=argparse.BooleanOptionalAction, default=None)
    p.add_argument("--version", "--ntrip-version", dest="versions", nargs="+", choices=VERSIONS,
                   help="the NTRIP versions it speaks (default both)")
    p.add_argument("--credentials", metavar="FILE")
    p.add_argument("--user")
    p.add_argument("--tls-cert", dest="tls_cert", metavar="PEM")
    p.add_argument("--tls-key", dest="tls_key", metavar="PEM")
    p.add_argument("--drop-every-s", type=float, dest="drop_every_s", metavar="S")
    p.add_argument("--garbage-every-s", type=float, dest="garbage_every_s", metavar="S")
    p.add_argument("--flood-bytes-per-s", type=float, dest="flood_bytes_per_s", metavar="B")
    p.add_argument("--log-level", default="INFO")
    return p


def settings_of(args: argparse.Namespace) -> CasterSettings:
    """The defaults, overlaid with the --config file's [caster] table, then the flags."""
    layers = []
    sim_origin = None
    if args.config:
        toml = load_toml(args.config)
        layers.append((toml.get("caster", {}), f"{args.config} [caster]"))
        sim_origin = toml.get("sim", {}).get("origin")
    flags = {k: v for k, v in vars(args).items() if k not in ("config", "log_level") and v is not None}
    layers.append((flags, "command line"))
    s = load(CasterSettings, layers)
    if not s.origin:
        origin = load(CasterSettings, [({"origin": sim_origin or IST_ORIGIN}, f"{args.config} [sim] origin")]).origin
        s = dataclasses.replace(s, origin=origin)
    if len(s.origin) != 3:
        raise ConfigError(f"setting 'origin' must be 3 numbers [lat_deg, lon_deg, height_m], got {list(s.origin)}")
    return s


def caster_of(s: CasterSettings) -> CasterTwin:
    users = {}
    if s.credentials:
        login, made = credentials_for_caster(s.credentials, s.user)
        users[login.user] = login.password
        log.info("%s user %r %s %s", "made a login for" if made else "serving", login.user,
                 "in" if made else "from", s.credentials)
    try:
        mount = Mountpoint.at(s.origin, s.baseline_m, s.bearing_deg, station_id=s.station_id, seed=s.seed,
                              messages=s.messages, vrs=s.vrs, latency_s=s.latency_s)
    except ValueError as exc:
        raise ConfigError(f"[caster]: {exc}") from None
    caster = CasterTwin(s.host, s.port, {s.mountpoint: mount}, users, s.versions,
                        s.tls_cert or None, s.tls_key or None, seed=s.seed, icy_headers=s.icy_headers)
    caster.drop_every_s = s.drop_every_s
    caster.garbage_every_s = s.garbage_every_s
    caster.flood_bytes_per_s = s.flood_bytes_per_s
    return caster


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    setup_logging(args.log_level)
    stop = stop_on_signals()
    try:
        s = settings_of(args)
        caster = caster_of(s).start()
    except (ConfigError, CredentialsError, OSError) as exc:
        print(f"ntrip caster twin: {exc}", file=sys.stderr)
        return 2
    base = caster.mountpoints[s.mountpoint].base
    lat, lon, h = base.position
    log.info("base %d at %.6f, %.6f, %.1f m: %.0f m from the origin, sending %s", base.station_id, lat, lon, h,
             base.baseline_m(*s.origin), s.messages)
    print(f"READY ntrip://{caster.host}:{caster.port}/{s.mountpoint}", flush=True)
    try:
        stop.wait()
    finally:
        caster.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
