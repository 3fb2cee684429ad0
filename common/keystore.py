"""The car's keys: a private certificate authority and one certificate per identity.

Every process and person on a secured car proves who it is with a certificate signed by
the car's own CA (zenoh's mutual TLS). The certificate names the identity (its common
name, CN) and its role (its organizational unit, OU); the router's access control is
built from those two fields (common/access.py), so issuing a certificate is all it takes
to let a new person in, and the store holds nothing else to keep in step.

A key store is one directory per car (default `~/.config/viena/keys/<car>/`):

    ca.pem  ca.key            the car's CA (keep ca.key off the car once keys are issued)
    router.pem  router.key    the router's certificate, its addresses as subject alt names
    NAME.pem  NAME.key        one identity: gnss0, razor0, steering, estimator, pilot, ...

Private keys are written once with mode 0600 and never printed; an existing file is never
replaced unless asked (`force`). Every problem is a `KeyError`-free `SecurityError` whose
one line names the file and the fix.
"""
from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
import socket
import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from viena.common.access import ROLES
from viena.common.errors import ConfigError

CA = "ca"
ROUTER = "router"
ROUTER_ROLE = "router"
NAME = re.compile(r"^[a-z0-9][a-z0-9_-]{0,31}$")
#: the identities `viena keys init` creates: every process of the car, one pilot, one observer
STANDARD_IDENTITIES = {
    "gnss0": "gnss", "gnss1": "gnss", "razor0": "imu", "steering": "steering",
    "estimator": "estimator", "sim": "sim", "autopilot": "autopilot", "pilot": "pilot",
    "observer": "observer",
}
CA_DAYS = 3650
ROUTER_DAYS = 1825
IDENTITY_DAYS = 365
#: `viena keys list` warns this long before a certificate expires
EXPIRY_WARNING = dt.timedelta(days=30)


class SecurityError(ConfigError):
    """Keys that cannot be used: missing, expired, foreign, loose permissions, bad role."""


def default_dir(car: str) -> Path:
    """$VIENA_KEYS, else ~/.config/viena/keys/<car> ($XDG_CONFIG_HOME respected)."""
    if os.environ.get("VIENA_KEYS"):
        return Path(os.environ["VIENA_KEYS"]).expanduser()
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "viena" / "keys" / car


@dataclass(frozen=True)
class Identity:
    """One certificate of the store, as read from its file (checked by `KeyStore.identity`)."""

    name: str
    role: str
    cert: Path
    key: Path
    not_after: dt.datetime

    def expired(self, now: dt.datetime | None = None) -> bool:
        return (now or _now()) >= self.not_after


class KeyStore:
    """One car's keys in one directory. `KeyStore.for_car("elettra").identity("pilot")`."""

    def __init__(self, directory: str | Path, car: str):
        self.dir = Path(directory).expanduser()
        self.car = car

    @classmethod
    def for_car(cls, car: str, directory: str | Path | None = None) -> KeyStore:
        return cls(directory or default_dir(car), car)

    @property
    def ca_cert(self) -> Path:
        return self.dir / f"{CA}.pem"

    @property
    def ca_key(self) -> Path:
        return self.dir / f"{CA}.key"

    def exists(self) -> bool:
        return self.ca_cert.exists()

    # -- creating -------------------------------------------------------------------------
    def init(self, router_hosts: Sequence[str] = (), force: bool = False) -> list[Identity]:
        """A new CA, the router's certificate and the standard identities."""
        if self.exists() and not force:
            raise SecurityError(f"{self.ca_cert}: a CA already exists for car '{self.car}' "
                                f"(`viena keys list` shows it; --force replaces every key)")
        self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        self.dir.chmod(0o700)
        key = _new_key()
        name = _name(f"viena {self.car} CA", "ca", self.car)
        cert = _builder(name, name, key.public_key(), CA_DAYS).add_extension(
            _x509().BasicConstraints(ca=True, path_length=0), critical=True).add_extension(
            _x509().KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                             content_commitment=False, key_encipherment=False,
                             data_encipherment=False, key_agreement=False, encipher_only=False,
                             decipher_only=False), critical=True).add_extension(
            _x509().SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        _write_key(self.ca_key, key, force)
        _write_cert(self.ca_cert, cert.sign(key, _sha256()))
        made = [self.issue(ROUTER_ROLE, ROUTER, router_hosts=router_hosts, force=force)]
        made += [self.issue(role, who, force=force) for who, role in STANDARD_IDENTITIES.items()]
        return made

    def issue(self, role: str, name: str, days: int | None = None, force: bool = False,
              router_hosts: Sequence[str] = (), valid_from: dt.datetime | None = None) -> Identity:
        """A certificate and key for `name` in `role`, signed by the car's CA.

        `valid_from` exists for tests that need a certificate that has already expired."""
        x509 = _x509()
        if role not in ROLES and role != ROUTER_ROLE:
            raise SecurityError(f"unknown role '{role}' (roles: {', '.join(sorted(ROLES))})")
        if not NAME.match(name) or name == CA or (name == ROUTER) != (role == ROUTER_ROLE):
            raise SecurityError(f"'{name}' cannot name an identity: use lower-case letters, digits, "
                                f"- and _ (at most 32), not '{CA}', and '{ROUTER}' only for the router")
        ca_key, ca_cert = self._load_ca()
        key = _new_key()
        days = days or (ROUTER_DAYS if role == ROUTER_ROLE else IDENTITY_DAYS)
        usage = x509.oid.ExtendedKeyUsageOID
        builder = _builder(_name(name, role, self.car), ca_cert.subject, key.public_key(), days,
                           valid_from).add_extension(
            x509.BasicConstraints(ca=False, path_length=None), critical=True).add_extension(
            x509.ExtendedKeyUsage([usage.SERVER_AUTH] if role == ROUTER_ROLE else [usage.CLIENT_AUTH]),
            critical=False).add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        if role == ROUTER_ROLE:
            builder = builder.add_extension(
                x509.SubjectAlternativeName(_alt_names(router_hosts)), critical=False)
        cert_path, key_path = self.dir / f"{name}.pem", self.dir / f"{name}.key"
        _write_key(key_path, key, force)
        cert = builder.sign(ca_key, _sha256())
        _write_cert(cert_path, cert)
        return Identity(name, role, cert_path, key_path, cert.not_valid_after_utc)

    # -- reading ----------------------------------------------------------------------------
    def identities(self) -> list[Identity]:
        """Every certificate in the store but the CA's, valid or not (for listing)."""
        found = []
        for path in sorted(self.dir.glob("*.pem")):
            if path.stem == CA:
                continue
            try:
                cert = _load_cert(path)
            except SecurityError:
                continue
            name, role = _subject(cert)
            found.append(Identity(name, role, path, path.with_suffix(".key"), cert.not_valid_after_utc))
        return found

    def identity(self, name: str) -> Identity:
        """The identity `name`, checked as the router would check it and more: its key is
        there, private to its owner and matches; it is signed by this car's CA, in date,
        and its role is known. Anything else is a SecurityError with the fix."""
        self._require_store()
        cert_path, key_path = self.dir / f"{name}.pem", self.dir / f"{name}.key"
        if not cert_path.exists():
            have = ", ".join(i.name for i in self.identities()) or "none"
            raise SecurityError(f"no identity '{name}' in {self.dir} (have: {have}): "
                                f"`viena keys issue ROLE {name}` creates one")
        cert = _load_cert(cert_path)
        cn, role = _subject(cert)
        if cn != name:
            raise SecurityError(f"{cert_path}: certificate is for '{cn}', not '{name}'")
        if role not in ROLES and role != ROUTER_ROLE:
            raise SecurityError(f"{cert_path}: unknown role '{role}' (roles: {', '.join(sorted(ROLES))})")
        _check_signed(cert, self._ca_cert_object(), cert_path, self.ca_cert)
        _check_dates(cert, cert_path, f"`viena keys issue {role} {name} --force`")
        key = _load_key(key_path)
        if key.public_key().public_numbers() != cert.public_key().public_numbers():
            raise SecurityError(f"{key_path}: this key does not belong to {cert_path}: "
                                f"re-issue with `viena keys issue {role} {name} --force`")
        return Identity(cn, role, cert_path, key_path, cert.not_valid_after_utc)

    def export(self, names: list[str], target: KeyStore, force: bool = False) -> list[Identity]:
        """Copy the CA certificate (never its key) and these identities into `target`: what
        another machine needs to run them (the Pi, or a laptop the estimator moves to)."""
        identities = [self.identity(name) for name in names]
        target.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        target.dir.chmod(0o700)
        if not target.ca_cert.exists() or force:
            target.ca_cert.write_bytes(self.ca_cert.read_bytes())
        elif target.ca_cert.read_bytes() != self.ca_cert.read_bytes():
            raise SecurityError(f"{target.ca_cert}: another CA is there (--force replaces it)")
        for ident in identities:
            _write_private(target.dir / ident.key.name, ident.key.read_bytes(), force)
            (target.dir / ident.cert.name).write_bytes(ident.cert.read_bytes())
        return [target.identity(name) for name in names]

    def router(self) -> Identity:
        return self.identity(ROUTER)

    def client_identities(self) -> list[Identity]:
        """Every usable client identity: what the router's access control lets in."""
        out = []
        for ident in self.identities():
            if ident.role == ROUTER_ROLE or ident.expired():
                continue
            try:
                out.append(self.identity(ident.name))
            except SecurityError:
                continue
        return out

    def _require_store(self) -> None:
        if not self.ca_cert.exists():
            raise SecurityError(f"no keys for car '{self.car}' in {self.dir}: create them with "
                                f"`viena keys init --router-host ADDRESS`, or point --keys / "
                                f"VIENA_KEYS at them")

    def _ca_cert_object(self):
        self._require_store()
        cert = _load_cert(self.ca_cert)
        _check_dates(cert, self.ca_cert, "`viena keys init --force` (a new CA: re-issue everything)")
        return cert

    def _load_ca(self):
        cert = self._ca_cert_object()
        if not self.ca_key.exists():
            raise SecurityError(f"{self.ca_key}: missing: certificates are issued where the CA key "
                                f"is kept (copy the new certificate and key here afterwards)")
        return _load_key(self.ca_key), cert


# -- helpers: cryptography is imported only when keys are used --------------------------------
def _x509():
    import cryptography.x509.oid  # noqa: F401  (x509.oid)
    from cryptography import x509
    return x509


def _sha256():
    from cryptography.hazmat.primitives import hashes
    return hashes.SHA256()


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ec
    return ec.generate_private_key(ec.SECP256R1())


def _name(common_name: str, role: str, car: str):
    x509 = _x509()
    oid = x509.oid.NameOID
    return x509.Name([x509.NameAttribute(oid.ORGANIZATION_NAME, f"viena {car}"),
                      x509.NameAttribute(oid.ORGANIZATIONAL_UNIT_NAME, role),
                      x509.NameAttribute(oid.COMMON_NAME, common_name)])


def _subject(cert) -> tuple[str, str]:
    oid = _x509().oid.NameOID
    def first(attr):
        values = cert.subject.get_attributes_for_oid(attr)
        return str(values[0].value) if values else ""
    return first(oid.COMMON_NAME), first(oid.ORGANIZATIONAL_UNIT_NAME)


def _builder(subject, issuer, public_key, days: int, valid_from: dt.datetime | None = None):
    start = valid_from or _now() - dt.timedelta(minutes=5)    # small clock differences
    return (_x509().CertificateBuilder().subject_name(subject).issuer_name(issuer)
            .public_key(public_key).serial_number(_x509().random_serial_number())
            .not_valid_before(start).not_valid_after(start + dt.timedelta(days=days)))


def _alt_names(hosts: Sequence[str]) -> list:
    """The router's names: localhost, this machine's name, and every address given."""
    x509 = _x509()
    names = ["localhost", "127.0.0.1", "::1", socket.gethostname(), f"{socket.gethostname()}.local",
             *hosts]
    out, seen = [], set()
    for host in names:
        if not host or host in seen:
            continue
        seen.add(host)
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            out.append(x509.DNSName(host))
    return out


def _write_key(path: Path, key, force: bool) -> None:
    from cryptography.hazmat.primitives import serialization
    _write_private(path, key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()), force)


def _write_private(path: Path, data: bytes, force: bool) -> None:
    """0600 from the first byte; an existing file is an error unless `force`."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    try:
        fd = os.open(path, flags, 0o600)
    except FileExistsError:
        raise SecurityError(f"{path}: exists; not replaced (--force replaces it)") from None
    with os.fdopen(fd, "wb") as f:
        os.fchmod(f.fileno(), 0o600)
        f.write(data)


def _write_cert(path: Path, cert) -> None:
    from cryptography.hazmat.primitives import serialization
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    path.chmod(0o644)


def _load_cert(path: Path):
    try:
        return _x509().load_pem_x509_certificate(path.read_bytes())
    except FileNotFoundError:
        raise SecurityError(f"{path}: missing") from None
    except ValueError:
        raise SecurityError(f"{path}: not a PEM certificate") from None


def _load_key(path: Path):
    from cryptography.hazmat.primitives import serialization
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise SecurityError(f"{path}: missing: the certificate beside it is useless without "
                            f"its key (copy the key here, or re-issue with --force)") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SecurityError(f"{path}: readable by others (mode {stat.S_IMODE(mode):04o}): "
                            f"run `chmod 600 {path}`")
    try:
        return serialization.load_pem_private_key(path.read_bytes(), password=None)
    except (ValueError, TypeError):
        raise SecurityError(f"{path}: not an unencrypted PEM private key") from None


def _check_dates(cert, path: Path, fix: str) -> None:
    now = _now()
    if now < cert.not_valid_before_utc:
        raise SecurityError(f"{path}: not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC "
                            f"(is this machine's clock right?)")
    if now >= cert.not_valid_after_utc:
        raise SecurityError(f"{path}: expired on {cert.not_valid_after_utc:%Y-%m-%d}: re-issue with {fix}")


def _check_signed(cert, ca_cert, path: Path, ca_path: Path) -> None:
    try:
        cert.verify_directly_issued_by(ca_cert)
    except Exception:
        raise SecurityError(f"{path}: not signed by this car's CA ({ca_path}): it belongs to "
                            f"another car or another key store; issue it here") from None
