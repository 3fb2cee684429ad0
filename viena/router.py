"""`viena router`: a zenoh session in router mode, for machines without zenohd.

It reads the same JSON5 file zenohd would (compose/zenoh/router.json5, or --zenoh-config),
so a user with zenohd can run `zenohd -c compose/zenoh/router.json5` instead (the secured
car needs the TLS and access-control settings this command adds from the key store).
`--config FILE` is viena's settings file (TOML), as for every viena process: its [zenoh]
table may give `listen`, `connect` and `config` (the JSON5 file); flags win over it.

Listening on `tls/...` secures the router: every client must present a certificate signed
by the car's CA (mutual TLS) and may do only what its role allows (common/access.py).
A plain `tcp/` listener reachable from other machines is refused unless `--insecure`
is given (or VIENA_INSECURE=1, which `viena up --insecure` sets); an insecure router
says so in its log every minute.

What an outsider can cost it before authenticating is bounded on every tls/ listener (a
short TLS handshake timeout; a connection that says nothing never reaches zenoh:
viena/router_guard.py), and what zenoh refuses (access control, the limits of
router.json5, failed TLS handshakes) is in the log, one line per cause per 10 s
(viena/router_log.py).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
from pathlib import Path

from viena.common.config import ConfigError, load_toml, load_zenoh_config
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import KeyStore
from viena.common.log import setup_logging
from viena.common.paths import router_config
from viena.common.secure import is_loopback, is_secure, secure_router
from viena.common.session import add_version_flag, check_endpoint, config_endpoints
from viena.common.signals import exit_if_stuck, stop_on_signals
from viena.router_guard import DEFER_ACCEPT_S, HANDSHAKE_TIMEOUT_MS, defer_silent_connections, with_handshake_timeout
from viena.router_log import ZenohLog

log = logging.getLogger("viena.router")
INSECURE_WARNING_PERIOD_S = 60.0


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena router", description=__doc__)
    parser.add_argument("--listen", metavar="ENDPOINT", action="append",
                        help="where to listen, e.g. tls/0.0.0.0:7447 (repeatable; "
                             "default: the config file's listen endpoints)")
    parser.add_argument("--connect", metavar="ENDPOINT", action="append",
                        help="another router to join (repeatable)")
    parser.add_argument("--config", metavar="FILE", type=Path, default=None,
                        help="viena settings file (TOML); its [zenoh] table may give 'listen', "
                             "'connect' and 'config' (a zenoh JSON5 file)")
    parser.add_argument("--zenoh-config", metavar="FILE", type=Path, default=None,
                        help=f"zenoh JSON5 config, as zenohd reads it (default {router_config()})")
    parser.add_argument("--car", default=DEFAULT_CAR, metavar="NAME",
                        help=f"whose key store secures tls/ listeners (default {DEFAULT_CAR})")
    parser.add_argument("--keys", metavar="DIR",
                        help="the car's key store (default $VIENA_KEYS, else ~/.config/viena/keys/CAR)")
    parser.add_argument("--insecure", action="store_true",
                        help="allow a plain tcp/ listener other machines can reach (no TLS, no "
                             "access control: anyone on that network can steer)")
    parser.add_argument("--tls-handshake-timeout-ms", type=int, default=HANDSHAKE_TIMEOUT_MS, metavar="MS",
                        help=f"TLS handshake timeout of every tls/ listener that sets none (zenoh's "
                             f"endpoint setting tls_handshake_timeout_ms; default {HANDSHAKE_TIMEOUT_MS}, "
                             f"0: zenoh's 10 s)")
    parser.add_argument("--defer-accept-s", type=int, default=DEFER_ACCEPT_S, metavar="S",
                        help=f"on a secured router, a TCP connection reaches zenoh once it sends its "
                             f"first bytes, or after S seconds (Linux TCP_DEFER_ACCEPT; default "
                             f"{DEFER_ACCEPT_S}, 0: off)")
    parser.add_argument("--log-level", default="INFO", metavar="LEVEL",
                        help="DEBUG, INFO, WARNING or ERROR (default INFO)")
    if "--version" not in parser._option_string_actions:
        add_version_flag(parser)
    return parser


def router_settings(args: argparse.Namespace) -> tuple[Path, list[str] | None, list[str] | None]:
    """The JSON5 file, listen and connect endpoints: flags, then --config's [zenoh] table,
    then the shipped router.json5."""
    if args.config and str(args.config).endswith((".json5", ".json")):
        raise ConfigError(f"--config {args.config}: --config takes viena settings (TOML); a zenoh "
                          f"JSON5 file goes to --zenoh-config")
    table = load_toml(args.config).get("zenoh", {}) if args.config else {}
    source = f"{args.config} [zenoh]"
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: must be a table")
    path = args.zenoh_config
    if path is None and table.get("config"):
        path = Path(table["config"])
        path = path if path.is_absolute() else Path(args.config).parent / path
    ends = {}
    for name in ("listen", "connect"):
        given = getattr(args, name)
        value = given if given else table.get(name)
        value = [value] if isinstance(value, str) else value
        where = f"--{name}" if given else f"{source} {name}"
        ends[name] = [check_endpoint(e, where) for e in value] if value else None
    return path or router_config(), ends["listen"], ends["connect"]


def bound_handshakes(conf, timeout_ms: int) -> None:
    """A TLS handshake timeout on every tls/ listener that sets none (router_guard.py)."""
    listen = config_endpoints(conf, "listen")
    bounded = [with_handshake_timeout(e, timeout_ms) for e in listen]
    if bounded != listen:
        conf.insert_json5("listen/endpoints", json.dumps(bounded))


def secure(conf, args: argparse.Namespace) -> str:
    """Secure `conf` as its listeners require; returns what the log should say about it."""
    listen = config_endpoints(conf, "listen")
    plain = [e for e in listen if not is_secure(e)]
    insecure = args.insecure or os.environ.get("VIENA_INSECURE") == "1"
    if any(is_secure(e) for e in listen):
        if plain:
            raise ConfigError(f"{', '.join(plain)} next to a tls/ listener: on a secured router "
                              f"every client presents a certificate, so listen on tls/ only")
        clients = secure_router(conf, KeyStore.for_car(args.car, args.keys))
        names = ", ".join(f"{i.name} ({i.role})" for i in clients)
        return f"secured: mutual TLS and access control; identities: {names or 'none'}"
    exposed = [e for e in plain if not is_loopback(e)]
    if exposed and not insecure:
        raise ConfigError(
            f"refusing to listen on {', '.join(exposed)} without TLS: anyone on that network "
            f"could steer the car. Create keys (`viena keys init --router-host ADDRESS`) and "
            f"listen on tls/, or pass --insecure on a network you trust")
    return f"INSECURE: {', '.join(exposed)} without TLS or access control" if exposed else "loopback only"


def run(args: argparse.Namespace) -> int:
    import zenoh

    zenoh_log = ZenohLog.capture()          # first: zenoh's log can be started once
    setup_logging(args.log_level)
    try:
        path, listen, connect = router_settings(args)
        conf = load_zenoh_config(path, mode="router", listen=listen, connect=connect)
        bound_handshakes(conf, args.tls_handshake_timeout_ms)
        security = secure(conf, args)
    except ConfigError as exc:
        print(f"viena router: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        print(f"viena router: cannot start: {str(exc).split(' at ')[0]}", file=sys.stderr)
        return 1
    zenoh_log.session = session
    if security.startswith("secured"):
        deferred = defer_silent_connections(args.defer_accept_s)
        if deferred:
            log.info("connections that say nothing wait %d s before zenoh sees them (%s)",
                     args.defer_accept_s, ", ".join(deferred))
    listening = config_endpoints(conf, "listen") or listen
    log.info("router %s listening on %s (config %s); %s", session.zid(), ", ".join(listening or []),
             path, security)
    _wait(stop, security)
    exit_if_stuck(log)                           # zenoh can hang closing a busy router
    session.close()
    log.info("router stopped")
    return 0



def _wait(stop: threading.Event, security: str) -> None:
    """Until stopped; an insecure router repeats its warning so nobody forgets it."""
    if not security.startswith("INSECURE"):
        stop.wait()
        return
    while True:
        log.warning("%s: anyone on the network can steer the car", security)
        if stop.wait(INSECURE_WARNING_PERIOD_S):
            return


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
