"""Opening a zenoh session the same way in every process, from the same flags.

    --connect ENDPOINT   client mode, connected to the router at ENDPOINT (repeatable)
    --car NAME           which car's keys (viena/NAME/...)
    --config FILE        viena TOML settings (its [zenoh] table may name a JSON5 file)

Without --connect or a [zenoh] table, a process is a client of the router on this machine
(tcp/127.0.0.1:7447): the Pi's shape, where every process meets at the local router.
"""
from __future__ import annotations

import argparse
import logging
import threading
from pathlib import Path

from viena.common.config import ConfigError, load_toml, load_zenoh_config
from viena.common.keys import DEFAULT_CAR

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
log = logging.getLogger(__name__)


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("connection (same in every viena process)")
    g.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help=f"connect in client mode to the zenoh router at ENDPOINT, e.g. "
                        f"tcp/192.168.1.10:7447 (repeatable; default {DEFAULT_ROUTER})")
    g.add_argument("--car", metavar="NAME",
                   help=f"car name: keys live under viena/NAME/ (default {DEFAULT_CAR})")
    g.add_argument("--config", metavar="FILE", type=Path,
                   help="viena settings file (TOML); its [zenoh] table may give 'connect', "
                        "'mode' or 'config' (a zenoh JSON5 file)")
    g.add_argument("--log-level", default="INFO", metavar="LEVEL",
                   help="DEBUG, INFO, WARNING or ERROR (default INFO)")


def load_settings_file(args: argparse.Namespace) -> dict:
    return load_toml(args.config) if getattr(args, "config", None) else {}


def car_name(args: argparse.Namespace, toml: dict) -> str:
    car = getattr(args, "car", None) or toml.get("car") or DEFAULT_CAR
    if not isinstance(car, str):
        raise ConfigError(f"{args.config}: setting 'car' must be text")
    return car


def zenoh_config(args: argparse.Namespace, toml: dict, default_mode: str = "client"):
    """The session config: --connect wins, then the TOML [zenoh] table, then the local router."""
    table = toml.get("zenoh", {})
    source = f"{getattr(args, 'config', None)} [zenoh]"
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: must be a table")
    unknown = set(table) - {"connect", "mode", "config", "listen"}
    if unknown:
        raise ConfigError(f"{source}: unknown setting '{sorted(unknown)[0]}' (known: config, connect, listen, mode)")
    file = table.get("config")
    if file is not None:
        file = Path(file)
        if not file.is_absolute() and getattr(args, "config", None):
            file = Path(args.config).parent / file
    connect = getattr(args, "connect", None) or _as_list(table.get("connect"), source, "connect")
    listen = _as_list(table.get("listen"), source, "listen")
    mode = "client" if getattr(args, "connect", None) else table.get("mode")
    if file is None and not connect and not listen:
        connect = [DEFAULT_ROUTER]
    if file is None and mode is None:
        mode = default_mode
    return load_zenoh_config(file, mode=mode, connect=connect, listen=listen)


def _as_list(value, source: str, name: str) -> list[str] | None:
    if value is None:
        return None
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return value
    raise ConfigError(f"{source}: setting '{name}' must be an endpoint or a list of endpoints")


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT (Ctrl-C): how a command-line tool learns to stop."""
    import signal

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def open_session(conf, stop: threading.Event | None = None, what: str = "router"):
    """zenoh.open, retried with backoff while the router is not there yet (a client fails
    at once without it); None if `stop` is set first."""
    import zenoh

    delay, said = 0.1, False
    while True:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            if not said:
                log.warning("cannot reach the %s yet (%s); retrying", what, str(exc).split(" at ")[0])
                said = True
            if stop is None:
                stop = threading.Event()
            if stop.wait(delay):
                return None
            delay = min(delay * 2, 1.0)
            continue
        if said:
            log.info("connected")
        return session
