"""How `viena up` secures a profile, and when it refuses to start one.

A profile's links are TLS or plain TCP by one variable, VIENA_LINK, that its files use in
every endpoint (`${VIENA_LINK:-tls}/localhost:7447`); the default written there is the
profile's own (`pi` and `laptop`: tls; `sim`: tcp on 127.0.0.1). `--secure` and
`--insecure` choose for one run. With TLS, every program presents the identity named
like the program (gnss0, steering, estimator, ...), so those certificates must exist
before anything starts. Without TLS, a router that other machines can reach is refused
unless the person said `--insecure`.
"""
from __future__ import annotations

import re
import time
from pathlib import Path

from viena.common.errors import ConfigError
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import PROGRAM_IDENTITY, Identity, KeyStore
from viena.common.secure import IDENTITIES_CHECKED, checked_identities, is_loopback
from viena.common.x509util import load_cert

_PROGRAM = re.compile(r"^\[program:([^\]]+)\]", re.M)
_ENV = re.compile(r"%\(ENV_([A-Z0-9_]+)\)s")
_ROUTER_LISTEN = re.compile(r"viena\.router\b[^\n]*?--listen\s+(\S+)")
_CAR = re.compile(r'^car\s*=\s*"([^"]+)"', re.M)


class SecurityRefusal(Exception):
    """Why a profile may not start as asked: one line a person can act on; `failed`, the
    identities whose check failed (if that was why)."""

    def __init__(self, message: str, failed: tuple[str, ...] = ()):
        super().__init__(message)
        self.failed = failed


def profile_text(conf: Path) -> str:
    """The profile's supervisord file with the program files it includes."""
    text = conf.read_text()
    m = re.search(r"^files\s*=\s*(.+)$", text, re.M)
    for name in (m.group(1).split() if m else []):
        path = conf.parent / name
        if path.exists():
            text += "\n" + path.read_text()
    return text


#: programs of a profile that open no zenoh session, so need no identity: the NTRIP
#: caster's twin (a TCP server the sim profile runs with `up --rtk`)
WITHOUT_IDENTITY = frozenset({"caster"})
_AUTOSTART_ENV = re.compile(r"^autostart\s*=\s*%\(ENV_([A-Z0-9_]+)\)s", re.M)


def programs(conf: Path, env: dict[str, str] | None = None) -> list[str]:
    """The profile's programs; given the run's environment, only those it starts (a
    program whose `autostart` is an environment variable, the corrections chain's, starts
    when that says true)."""
    text = profile_text(conf)
    names = []
    for match in _PROGRAM.finditer(text):
        block = text[match.end():].split("\n[", 1)[0]
        optional = _AUTOSTART_ENV.search(block)
        if env is not None and optional and env.get(optional.group(1), "false").lower() != "true":
            continue
        names.append(match.group(1))
    return names


def router_listen(conf: Path, env: dict[str, str]) -> str | None:
    """Where the profile's router listens, with the environment filled in; None if none."""
    m = _ROUTER_LISTEN.search(profile_text(conf))
    return _ENV.sub(lambda v: env.get(v.group(1), v.group(0)), m.group(1)) if m else None


def car_of(settings: Path) -> str:
    m = _CAR.search(settings.read_text()) if settings.exists() else None
    return m.group(1) if m else DEFAULT_CAR


def secure_environment(conf: Path, env: dict[str, str], secure: bool, insecure: bool,
                       keys: str | None) -> dict[str, str]:
    """VIENA_LINK, VIENA_CAR, VIENA_KEYS and VIENA_INSECURE for this run, after checking
    that the keys it needs are there; raises SecurityRefusal otherwise."""
    if secure and insecure:
        raise SecurityRefusal("--secure and --insecure contradict each other")
    link = "tls" if secure else "tcp" if insecure else env.get("VIENA_LINK", "tcp")
    out = {"VIENA_LINK": link, "VIENA_CAR": car_of(Path(env["VIENA_SETTINGS"]))}
    if link == "tls":
        store = KeyStore.for_car(out["VIENA_CAR"], keys)
        out["VIENA_KEYS"] = str(store.dir.resolve())
        checked_at = time.time()
        names = [p for p in programs(conf, env) if p not in WITHOUT_IDENTITY]
        names = [PROGRAM_IDENTITY.get(name, name) for name in names]      # the identity each presents
        checked = _check_identities(store, names)
        ca_expiry = load_cert(store.ca_cert).not_valid_after_utc.timestamp()
        expiries = [i.not_after.timestamp() for i in checked] + [ca_expiry]
        out[IDENTITIES_CHECKED] = checked_identities(names, expiries, checked_at)   # no program checks again
        return out
    listen = router_listen(conf, {**env, **out})
    if listen and not is_loopback(listen) and not insecure:
        raise SecurityRefusal(
            f"the router would listen on {listen} without TLS or access control: anyone on that "
            f"network could steer the car. Create keys first (`viena keys init --router-host "
            f"<this machine's address>`), or add --insecure on a network you trust")
    if insecure:
        out["VIENA_INSECURE"] = "1"
    return out


def _check_identities(store: KeyStore, names: list[str]) -> list[Identity]:
    problems: dict[str, str] = {}
    checked = []
    for name in names:
        try:
            checked.append(store.identity(name))
        except ConfigError as exc:
            if not store.exists():
                raise SecurityRefusal(f"{exc} (or `viena up --insecure` without TLS)") from None
            problems[name] = str(exc)
    if problems:
        raise SecurityRefusal("; ".join(problems.values()), failed=tuple(problems))
    return checked
