"""Opening a zenoh session the same way in every process, from the same flags.

    --connect ENDPOINT   client mode, connected to the router at ENDPOINT (repeatable)
    --car NAME           which car's keys (viena/NAME/...)
    --config FILE        viena TOML settings (its [zenoh] table may name a JSON5 file)
    --identity NAME      who this process is on a secured (tls/) link: a certificate of
                         the car's key store (default: the service's own unit or name;
                         for people's tools $VIENA_IDENTITY, else `observer`)
    --keys DIR           the car's key store (default $VIENA_KEYS, else
                         ~/.config/viena/keys/<car>)

Without --connect or a [zenoh] table, a process is a client of the router on this machine
(tcp/127.0.0.1:7447): the Pi's shape, where every process meets at the local router.
A `tls/` endpoint makes the session present its identity (common/secure.py).
"""
from __future__ import annotations

import argparse
import logging
import os
import threading
from pathlib import Path

from viena.common.config import ConfigError, load_toml, load_zenoh_config
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import KeyStore
from viena.common.secure import is_secure, secure_client

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
#: the identity of a person's tool (viena sub, monitor, record...) when none is given
PERSON_IDENTITY = "observer"
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
    g.add_argument("--identity", metavar="NAME",
                   help="on a secured (tls/) link: which certificate of the car's key store to "
                        "present (see `viena keys list`)")
    g.add_argument("--keys", metavar="DIR", type=Path,
                   help="the car's key store (default $VIENA_KEYS, else ~/.config/viena/keys/CAR)")
    g.add_argument("--log-level", default="INFO", metavar="LEVEL",
                   help="DEBUG, INFO, WARNING or ERROR (default INFO)")


def load_settings_file(args: argparse.Namespace) -> dict:
    return load_toml(args.config) if getattr(args, "config", None) else {}


def car_name(args: argparse.Namespace, toml: dict) -> str:
    car = getattr(args, "car", None) or toml.get("car") or DEFAULT_CAR
    if not isinstance(car, str):
        raise ConfigError(f"{args.config}: setting 'car' must be text")
    return car


def zenoh_config(args: argparse.Namespace, toml: dict, default_mode: str = "client",
                 identity: str | None = None):
    """The session config: --connect wins, then the TOML [zenoh] table, then the local router.

    On a `tls/` endpoint the session presents an identity: --identity, else `identity`
    (a service passes its own unit or name), else $VIENA_IDENTITY, else `observer`."""
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
    conf = load_zenoh_config(file, mode=mode, connect=connect, listen=listen)
    if any(is_secure(e) for e in config_endpoints(conf, "connect")):
        name = (getattr(args, "identity", None) or identity or os.environ.get("VIENA_IDENTITY")
                or PERSON_IDENTITY)
        store = KeyStore.for_car(car_name(args, toml), getattr(args, "keys", None))
        secure_client(conf, store, name)
    return conf


def config_endpoints(conf, what: str) -> list[str]:
    import json

    try:
        found = json.loads(conf.get_json(f"{what}/endpoints"))
    except Exception:
        return []
    if isinstance(found, dict):                # per-mode endpoints: {router: [...], ...}
        return [e for v in found.values() for e in (v or [])]
    return list(found or [])


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


class Unreachable(Exception):
    """No session within the time a person asked to wait: one line naming the endpoint."""


def open_session(conf, stop: threading.Event | None = None, what: str = "router",
                 timeout_s: float | None = None):
    """zenoh.open, retried with backoff while the router is not there yet (a client fails
    at once without it); None if `stop` is set first; Unreachable after `timeout_s`.

    On a TLS link a router that refuses our certificate looks the same as no router, so
    the message says both."""
    import time

    import zenoh

    delay, said = 0.1, False
    end = None if not timeout_s else time.monotonic() + timeout_s
    stop = stop or threading.Event()
    while True:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            why = str(exc).split(" at ")[0].strip()
            secure = any(is_secure(e) for e in config_endpoints(conf, "connect"))
            hint = " (or it refuses this identity's certificate)" if secure else ""
            if end is not None and time.monotonic() + delay > end:
                raise Unreachable(f"cannot reach the {what} in {timeout_s:g} s{hint}: {why}") from None
            if not said:
                log.warning("cannot reach the %s yet%s (%s); retrying", what, hint, why)
                said = True
            if stop.wait(delay):
                return None
            delay = min(delay * 2, 1.0)
            continue
        if said:
            log.info("connected")
        return session
