"""Turning a zenoh config into a secured one: zenoh's own TLS, mutual TLS and access control.

A link is secured when its endpoint says so (`tls/host:port`); there is no other switch.
A client on a `tls/` endpoint must present an identity of the car's key store, checked
before zenoh sees it, so a bad key is one line naming the file, never a silent fallback
to an open connection. A router listening on `tls/` demands a certificate from this car's
CA of every client (mTLS) and applies the access control built from the store's
certificates and revocation list (never its private keys). zenoh reads access control once,
when the router starts: a certificate issued or revoked since counts from the next start.
"""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

from viena.common import clock
from viena.common.access import access_control
from viena.common.keystore import Identity, KeyStore

SECURE_SCHEMES = ("tls/", "quic/")
LOOPBACK_HOSTS = ("127.", "localhost", "[::1]", "::1")
log = logging.getLogger("viena.router")


#: set by `viena up` for the programs it starts once it has checked their identities:
#: "CHECKED_AT:FIRST_EXPIRY:NAME,NAME,...", times in Unix seconds (`checked_identities`)
IDENTITIES_CHECKED = "VIENA_IDENTITIES_CHECKED"


def is_secure(endpoint: str) -> bool:
    return endpoint.startswith(SECURE_SCHEMES)


def is_loopback(endpoint: str) -> bool:
    """True for an endpoint only this machine can reach (tcp/127.0.0.1:7447)."""
    host = endpoint.split("/", 1)[-1]
    return host.startswith(LOOPBACK_HOSTS)


def _set(conf, path: str, value) -> None:
    conf.insert_json5(path, json.dumps(value))


def _tls_common(conf, store: KeyStore) -> None:
    _set(conf, "transport/link/tls/root_ca_certificate", str(store.ca_cert))
    _set(conf, "transport/link/tls/enable_mtls", True)
    _set(conf, "transport/link/tls/verify_name_on_connect", True)
    _set(conf, "transport/link/tls/close_link_on_expiration", True)


def secure_client(conf, store: KeyStore, name: str, checked: str | None = None) -> None:
    """Present identity `name` on every TLS link of this session, after checking it as the
    router will (dates, revocation, key), so a person reads why in one line.

    `checked` (IDENTITIES_CHECKED, from `viena up`, which checks every program's identity
    before it starts them): while that check still holds (`still_checked`), the identity's
    files are only found, and cryptography, some 10 MB of every process, is not loaded."""
    if still_checked(store, name, checked):
        cert, key = identity_files(store, name)
    else:
        identity = store.identity(name)
        cert, key = identity.cert, identity.key
    _tls_common(conf, store)
    _set(conf, "transport/link/tls/connect_certificate", str(cert))
    _set(conf, "transport/link/tls/connect_private_key", str(key))


def identity_files(store: KeyStore, name: str) -> tuple[Path, Path]:
    """The certificate and key of `name` (`still_checked` found them unchanged)."""
    cert = store.cert_path(name)
    return cert, cert.with_suffix(".key")


def checked_identities(names: list[str], expiries: list[float], checked_at: float) -> str:
    """IDENTITIES_CHECKED's value: the identities `names` checked from `checked_at` (Unix s)
    on, good until the first of `expiries` (theirs and the CA's)."""
    return f"{checked_at:.6f}:{math.floor(min(expiries, default=checked_at))}:{','.join(names)}"


def still_checked(store: KeyStore, name: str, checked: str | None) -> bool:
    """Whether `viena up`'s check holds for `name` now: `viena up` checked that identity,
    no certificate it checked (nor the CA's) has expired since, and neither the identity's
    certificate and key, the CA's certificate, the revocation list nor the store's directory
    have changed since (their ctime, which no copy sets back: a
    revocation or a new export copied onto the Pi is checked again). A program restarted
    hours later by supervisord is thus checked afresh whenever anything could differ."""
    try:
        at, expiry, names = (checked or "").split(":")
        checked_at, first_expiry = float(at), float(expiry)
    except ValueError:
        return False
    if name not in names.split(",") or clock.time() >= first_expiry:
        return False
    cert, key = identity_files(store, name)
    # the directory too: a file made, renamed or linked in it changes its ctime
    files = [store.dir, cert, key, store.ca_cert]
    if store.crl.exists():                  # (a store from before revocation lists has none)
        files.append(store.crl)
    try:
        return all(path.stat().st_ctime <= checked_at for path in files)
    except OSError:
        return False


def secure_router(conf, store: KeyStore) -> list[Identity]:
    """Listen with the router's certificate, admit only clients with a certificate of this
    car's CA, and let each do what its certificate's role allows (default deny); returns who
    is admitted. Each certificate of the store that cannot be used (another CA's, expired,
    revoked, unknown role, unreadable) is left out with one warning naming the file and why."""
    router = store.router()
    clients, skipped = store.client_certificates()
    for reason in skipped:
        log.warning("not admitted: %s", reason)
    _tls_common(conf, store)
    _set(conf, "transport/link/tls/listen_certificate", str(router.cert))
    _set(conf, "transport/link/tls/listen_private_key", str(router.key))
    _set(conf, "transport/link/protocols", ["tls", "quic"])
    _set(conf, "access_control",
         access_control(store.car, [(i.name, i.role, i.common_name) for i in clients]))
    return clients


def client_config_json5(store: KeyStore, name: str, connect: list[str]) -> str:
    """A complete zenoh client config for `name`, for the `zenoh` CLI or any zenoh program."""
    identity = store.identity(name)
    conf = {
        "mode": "client",
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": {
            "root_ca_certificate": str(store.ca_cert),
            "connect_certificate": str(identity.cert),
            "connect_private_key": str(identity.key),
            "enable_mtls": True,
            "verify_name_on_connect": True,
            "close_link_on_expiration": True,
        }}},
    }
    header = (f"// zenoh client config for '{name}' (role {identity.role}) of car '{store.car}',\n"
              f"// made by `viena keys zenoh-config`; certificate valid until "
              f"{identity.not_after:%Y-%m-%d}. Use: zenoh --config THIS_FILE ...\n")
    return header + json.dumps(conf, indent=2) + "\n"
