"""`viena ntrip sources CASTER[:PORT]`: a caster's mountpoints, nearest first.

    viena ntrip sources caster.example.org               # distances from the car's fix
    viena ntrip sources caster.example.org:443 --tls --credentials ~/.config/viena/ntrip/elettra.credentials
    viena ntrip sources 127.0.0.1:2101 --near 38.7369,-9.1427 [--json]

The source table's mountpoints with their format (RTCM 3.x, RTCM 2.x, CMR), messages,
navigation systems, whether the caster wants the rover's position (GGA: VRS and
nearest-base mountpoints) and the distance from the car: from the newest fix on the car's
bus (viena/<car>/gnss/*/fix) if one comes within a couple of seconds, else from --near.
A base more than a few tens of km away gives no RTK fix: choose the nearest that sends
what the receiver takes (docs/sensors.md#corrections). The login, when the caster wants
one for its table, comes from a file only its owner can read, never from this line.
"""
from __future__ import annotations

import argparse
import json
import math
import queue
import sys
import threading
import time

from viena.common.errors import InputError
from viena.common.samples import topics
from viena.common.schema import SampleError, unpack
from viena.common.session import add_common_arguments
from viena.tool import Connection, Fail, guarded, tool_logging

#: how long to listen for the car's fix
FIX_WAIT_S = 2.0


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena ntrip", description=__doc__,
                                               formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="ntrip_command", required=True, metavar="COMMAND")
    p = sub.add_parser("sources", help="a caster's mountpoints, nearest first",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("caster", metavar="CASTER[:PORT]", help="the caster's host, and port (default 2101)")
    p.add_argument("--tls", action="store_true", help="NTRIP over TLS")
    p.add_argument("--ca-file", metavar="FILE", default="", help="TLS: the CA of the caster's certificate")
    p.add_argument("--ntrip-version", choices=("2.0", "1.0"), default="2.0",
                   help="NTRIP version to ask in (default 2.0)")
    p.add_argument("--credentials", metavar="FILE", default="",
                   help="login file (one line user:password, mode 600), if the caster wants one for its table")
    p.add_argument("--near", metavar="LAT,LON", help="distances from here, not from the car's fix")
    p.add_argument("--json", action="store_true", help="one JSON object per mountpoint")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="longest wait for the caster (default 10)")
    add_common_arguments(p)
    return parser


def run(args: argparse.Namespace) -> int:
    return guarded("viena ntrip", _run, args)


def _run(args: argparse.Namespace) -> int:
    tool_logging(args)
    if args.ntrip_command != "sources":
        raise Fail(f"unknown command {args.ntrip_command}", 2)
    return sources(args)


def parse_caster(text: str) -> tuple[str, int]:
    """HOST[:PORT] (an IPv6 address in brackets) -> (host, port)."""
    host, port = text, 2101
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        if rest.startswith(":"):
            port = _port(rest[1:], text)
    elif text.count(":") == 1:
        host, port_text = text.split(":")
        port = _port(port_text, text)
    if not host:
        raise InputError(f"no host in {text!r}: give CASTER[:PORT]")
    return host, port


def _port(text: str, whole: str) -> int:
    if not text.isdigit() or not 0 < int(text) < 65536:
        raise InputError(f"bad port in {whole!r}: give CASTER[:PORT]")
    return int(text)


def parse_near(text: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--near {text!r}: give LAT,LON in degrees, e.g. 38.7369,-9.1427") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise InputError(f"--near {text!r}: latitude -90..90, longitude -180..180")
    return lat, lon


def car_position(args: argparse.Namespace, wait_s: float = FIX_WAIT_S) -> tuple[float, float] | None:
    """The newest valid fix on the car's bus within `wait_s`, or None (no router, no fix)."""
    from viena.common.samples.fix import FIX

    fields = FIX.reader("valid", "lat_deg", "lon_deg")
    try:
        link = Connection(args)
        session = link.open(threading.Event(), timeout_s=wait_s)
    except Fail:
        return None
    if session is None:
        return None
    got: queue.Queue = queue.Queue()
    sub = None
    try:
        sub = session.declare_subscriber(link.keys.of(topics.GNSS_FIX),
                                         lambda s: got.put(s.payload.to_bytes()))
        end = time.monotonic() + wait_s
        while (left := end - time.monotonic()) > 0:
            try:
                valid, lat, lon = fields(unpack(got.get(timeout=left), "fix"))
            except queue.Empty:
                break
            except SampleError:
                continue
            if valid:
                return lat, lon
    finally:
        if sub is not None:
            sub.undeclare()
        session.close()
    return None


def sources(args: argparse.Namespace) -> int:
    from viena.services.ntrip.driver.caster import CasterAddress, LinkError, fetch_sourcetable
    from viena.services.ntrip.driver.credentials import CredentialsError, read_credentials
    from viena.services.ntrip.driver.sourcetable import Mountpoint, by_distance, mountpoints

    try:
        host, port = parse_caster(args.caster)
        near = parse_near(args.near) if args.near else None
        credentials = read_credentials(args.credentials) if args.credentials else None
    except (InputError, CredentialsError) as exc:
        raise Fail(str(exc), 2) from None
    address = CasterAddress(host, port, "", args.ntrip_version, args.tls, args.ca_file)
    try:
        table = mountpoints(fetch_sourcetable(address, credentials, timeout_s=args.timeout))
    except LinkError as exc:
        raise Fail(f"{host}:{port}: {exc.why}", 1) from None
    where, said = near, "--near"
    if where is None:
        where, said = car_position(args), "the car's fix"
    rows: list[tuple[Mountpoint, float | None]]
    if where is None:
        print(f"# no fix on the car's bus within {FIX_WAIT_S:g} s: distances need --near LAT,LON",
              file=sys.stderr)
        rows = [(m, None) for m in sorted(table, key=lambda m: m.name)]
    else:
        rows = by_distance(table, *where)
    if args.json:
        for m, km in rows:
            print(json.dumps({**m._asdict(), "distance_km": None if km is None else round(km, 2)}))
        return 0
    if not rows:
        print(f"{host}:{port} lists no mountpoint")
        return 0
    if where is not None:
        print(f"# {len(rows)} mountpoints of {host}:{port}, nearest to {where[0]:.5f}, {where[1]:.5f} ({said}) first")
    print_table(rows)
    return 0


def print_table(rows) -> None:
    head = ("mountpoint", "km", "format", "messages", "systems", "GGA", "identifier")
    lines = [head]
    for m, km in rows:
        lines.append((m.name, "-" if km is None or not math.isfinite(km) else f"{km:.1f}", m.format,
                      _short(m.details, 36), m.nav_systems or "-", "yes" if m.wants_gga else "no",
                      _short(m.identifier, 24)))
    widths = [max(len(r[i]) for r in lines) for i in range(len(head))]
    for r in lines:
        print("  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip())


def _short(text: str, n: int) -> str:
    return text if len(text) <= n else text[:n - 3] + "..."


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
