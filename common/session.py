"""Opening a zenoh session the same way in every process, from the same flags.

    --connect ENDPOINT   client mode, connected to the router at ENDPOINT (repeatable)
    --car NAME           which car's keys (viena/NAME/...)
    --config FILE        viena TOML settings (its [zenoh] table may name a JSON5 file)
    --identity NAME      who this process is on a secured (tls/) link: a certificate of
                         the car's key store (default: the service's own unit or name;
                         for people's tools $VIENA_IDENTITY, else `observer`)
    --keys DIR           the car's key store (default $VIENA_KEYS, else
                         ~/.config/viena/keys/<car>)
    --version            viena's version, and zenoh's and Python's

Without --connect or a [zenoh] table, a process is a client of the profile running on this
machine (`viena up` saved where its clients connect, common/runstate.py), else of the router
on this machine (tcp/127.0.0.1:7447): the Pi's shape, where every process meets at the
local router. A `tls/` endpoint makes the session present its identity (common/secure.py).

Whatever a person typed is checked before zenoh sees it, so a malformed endpoint or key
expression is one line naming it; a router that cannot be reached is one line naming the
endpoint and what was found there (nothing listening, no answer, an unknown host).
"""
from __future__ import annotations

import argparse
import logging
import os
import re
import socket
import threading
from pathlib import Path

from viena.common.config import ConfigError, load_toml, load_zenoh_config
from viena.common.errors import InputError
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import KeyStore
from viena.common.secure import IDENTITIES_CHECKED, is_secure, secure_client
from viena.common.versions import version_text

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
#: the identity of a person's tool (viena sub, monitor, record...) when none is given
PERSON_IDENTITY = "observer"
#: protocols whose address is HOST:PORT, and the others zenoh knows
HOST_PORT_PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws")
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_ENDPOINT = re.compile(r"^(?P<protocol>[a-z0-9-]+)/(?P<address>[^?#]+)(?:\?[^#]*)?(?:#.*)?$")
_RUST_LOCATION = re.compile(r"\s+at /\S+\.rs:\d+\.?")
log = logging.getLogger(__name__)


class VersionAction(argparse.Action):
    """`--version`: viena's version, with zenoh's and Python's (read without importing them)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="print viena's version (and zenoh's and Python's) and exit"):
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {version_text()}")
        parser.exit()


def add_version_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action=VersionAction)


def check_endpoint(endpoint: str, source: str = "--connect") -> str:
    """`endpoint` if zenoh can use it, else one line saying how one is written."""
    m = _ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
    example = "e.g. tcp/127.0.0.1:7447 or tls/192.168.4.1:7447"
    if m is None:
        raise ConfigError(f"{source}: '{endpoint}' is not an endpoint: write PROTOCOL/HOST:PORT, {example}")
    protocol, address = m.group("protocol"), m.group("address")
    if protocol in HOST_PORT_PROTOCOLS:
        host, colon, port = address.rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ConfigError(f"{source}: '{endpoint}' needs HOST:PORT after {protocol}/, {example}")
    elif protocol not in OTHER_PROTOCOLS:
        raise ConfigError(f"{source}: '{endpoint}': unknown protocol '{protocol}' "
                          f"(known: {', '.join(HOST_PORT_PROTOCOLS + OTHER_PROTOCOLS)}), {example}")
    return endpoint


def check_keyexpr(keyexpr: str) -> str:
    """`keyexpr` if zenoh accepts it, else one line saying why not."""
    import zenoh

    try:
        return str(zenoh.KeyExpr(keyexpr))
    except (zenoh.ZError, ValueError, TypeError) as exc:
        why = _RUST_LOCATION.sub("", str(exc)).split("`: ", 1)[-1].strip()
        raise InputError(f"'{keyexpr}' is not a key expression: {why} "
                         f"(e.g. viena/elettra/gnss/*/fix, viena/elettra/**)") from None


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
    if "--version" not in parser._option_string_actions:
        add_version_flag(parser)


def load_settings_file(args: argparse.Namespace) -> dict:
    """The settings file's tables; `args.settings`, when a program was given its settings
    already read (the lockstep runner hands every program the same merged tables)."""
    given = getattr(args, "settings", None)
    if given is not None:
        return given
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
    given = getattr(args, "connect", None)
    connect = [check_endpoint(e) for e in given] if given else _as_list(table.get("connect"), source, "connect")
    listen = _as_list(table.get("listen"), source, "listen")
    for endpoint in ([] if given else connect or []) + (listen or []):
        check_endpoint(endpoint, source)
    mode = "client" if given else table.get("mode")
    keys = getattr(args, "keys", None)
    if file is None and not connect and not listen:
        connect, profile_env = _local_router()
        if keys is None and not os.environ.get("VIENA_KEYS"):
            keys = profile_env.get("VIENA_KEYS")
    if file is None and mode is None:
        mode = default_mode
    conf = load_zenoh_config(file, mode=mode, connect=connect, listen=listen)
    if any(is_secure(e) for e in config_endpoints(conf, "connect")):
        name = (getattr(args, "identity", None) or identity or os.environ.get("VIENA_IDENTITY")
                or PERSON_IDENTITY)
        store = KeyStore.for_car(car_name(args, toml), keys)
        secure_client(conf, store, name, checked=os.environ.get(IDENTITIES_CHECKED))
    return conf


def _local_router() -> tuple[list[str], dict[str, str]]:
    """Where the profile running on this machine says its clients connect (and its saved
    variables), else the router on this machine."""
    from viena.common.runstate import running_connect

    return running_connect() or ([DEFAULT_ROUTER], {})


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


class Unreachable(Exception):
    """No session within the time a person asked to wait: one line naming the endpoint."""


def describe_failure(endpoint: str) -> str:
    """What is at `endpoint` when zenoh cannot open a session there, in words a person
    can act on: an unknown host, nothing listening, no answer, or a router that refused."""
    m = _ENDPOINT.match(endpoint)
    if m is None or m.group("protocol") not in HOST_PORT_PROTOCOLS:
        return "no session"
    host, _, port = m.group("address").rpartition(":")
    host = host.strip("[]")
    try:
        addresses = socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError, ValueError):
        return f"unknown host '{host}'"
    if m.group("protocol") not in ("tcp", "tls", "ws"):
        return "no session"
    family, kind, proto, _, address = addresses[0]
    try:
        with socket.socket(family, kind, proto) as probe:
            probe.settimeout(1.0)
            probe.connect(address)
    except ConnectionRefusedError:
        return "nothing listens there (is the router up? `viena status`)"
    except OSError:
        return "no answer (a wrong address, a network not joined, or a firewall)"
    if is_secure(endpoint):
        return ("the router refused the session: it does not accept this identity's certificate "
                "(`viena keys list`), or it does not speak TLS there (try tcp/)")
    return "the router refused the session (does it listen with TLS there? try tls/)"


def open_session(conf, stop: threading.Event | None = None, what: str = "router",
                 timeout_s: float | None = None, on_wait=None):
    """zenoh.open, retried with backoff while the router is not there yet (a client fails
    at once without it); None if `stop` is set first; Unreachable after `timeout_s`, one
    line naming the endpoint and what was found there. `on_wait(why)` hears each failed
    attempt (a dashboard shows it)."""
    import time

    import zenoh

    delay, said = 0.1, False
    end = None if not timeout_s else time.monotonic() + timeout_s
    stop = stop or threading.Event()
    endpoints = config_endpoints(conf, "connect")
    where = f" at {', '.join(endpoints)}" if endpoints else ""
    while True:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError:
            why = "; ".join(dict.fromkeys(describe_failure(e) for e in endpoints)) or "no session"
            if on_wait is not None:
                on_wait(f"cannot reach the {what}{where}: {why}")
            if end is not None and time.monotonic() >= end:
                raise Unreachable(f"cannot reach the {what}{where} in {timeout_s:g} s: {why}") from None
            if not said and end is None and on_wait is None:    # else one line or a screen says it
                log.warning("cannot reach the %s yet%s: %s; retrying", what, where, why)
                said = True
            if stop.wait(delay if end is None else min(delay, max(0.0, end - time.monotonic()))):
                return None
            delay = min(delay * 2, 1.0)
            continue
        if said:
            log.info("connected")
        return session


def zenoh_options(topic) -> dict:
    """A publisher's (or a put's) quality of service for `topic` (common/samples/topics.py):
    zenoh's congestion control. Reliability is zenoh's default, reliable, on every topic."""
    import zenoh

    block = topic.congestion == "block"
    return {"congestion_control": zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP}
