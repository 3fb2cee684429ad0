"""The car's keys: a private certificate authority, one certificate per identity, and the
list of certificates it has revoked.

Every process and person on a secured car proves who it is with a certificate signed by
the car's own CA (zenoh's mutual TLS). The certificate says who it is and what it may do:

    common name (CN)            NAME.TAG: the identity's name, a dot, and TAG, the last 16
                                hex digits of the certificate's serial number; unique to this
                                one certificate (names have no dots, so the split is plain)
    organizational unit (OU)    the role (common/access.py)

zenoh's access control can match a client only by its certificate's common name, and
zenoh's TLS reads no revocation list. So the router (common/secure.py) lists, for each name,
the exact CN of its one current, unrevoked certificate, and grants that CN what the role in
that certificate says: an older certificate of the name carries another TAG, matches no
rule and gets nothing (default deny), whatever role it says. Certificates made before tags
(CN = NAME) are still read as NAME; re-issue them (`viena keys issue ROLE NAME --force`) so
that an older certificate of the same name cannot pass for them.

A key store is one directory per car (default `~/.config/viena/keys/<car>/`):

    ca.pem  ca.key            the car's CA (ca.key stays on the trusted machine, never the car)
    crl.pem                   the CA's revocation list (X.509 CRL, public: exported to the car)
    router.pem  router.key    the router's certificate, its addresses as subject alt names
    NAME.pem  NAME.key        one identity: gnss0, razor0, steering, estimator, pilot, ...
    NAME.pem                  a certificate alone: someone whose key is elsewhere (alice's is
                              on her laptop); the router admits them all the same
    revoked/NAME.SERIAL.pem   revoked certificates, kept to name the CRL's entries

The router's access control comes from certificates and the CRL (common/revocation.py) only,
never private keys; only a process presenting an identity needs its key. Private keys are
written once with mode 0600 and never printed; an existing file is never replaced unless asked
(`force`). Every problem is a `SecurityError` whose one line names the file and the fix
(common/x509util.py reads, writes and checks the files).
"""
from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
import socket
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from viena.common import revocation
from viena.common.access import ROLES
from viena.common.revocation import REASONS, Revoked
from viena.common.x509util import (
    SecurityError,
    check_dates,
    check_signed,
    copy_public,
    load_cert,
    load_key,
    now,
    subject,
    write_key,
    write_private,
    write_public,
)

CA = "ca"
CRL = "crl"
REVOKED = "revoked"
ROUTER = "router"
ROUTER_ROLE = "router"
NAME = re.compile(r"^[a-z0-9][a-z0-9_-]{0,31}$")
#: a certificate's common name is NAME.TAG, TAG this many hex digits of its serial number
TAG_DIGITS = 16
#: the identities `viena keys init` creates: every process of the car, one pilot, one observer
STANDARD_IDENTITIES = {
    "gnss0": "gnss", "gnss1": "gnss", "razor0": "imu", "steering": "steering",
    "estimator": "estimator", "sim": "sim", "autopilot": "autopilot", "pilot": "pilot",
    "observer": "observer", "ntrip": "ntrip", "recorder": "recorder",
}
#: the identity a program presents where it is not the program's own name (`viena up`
#: checks these for it): the pilot program drives as `autopilot`, the person as `pilot`
PROGRAM_IDENTITY = {"pilot": "autopilot"}
CA_DAYS = 3650
ROUTER_DAYS = 1825
IDENTITY_DAYS = 365
#: `viena keys list` warns this long before a certificate expires
EXPIRY_WARNING = dt.timedelta(days=30)


def default_dir(car: str) -> Path:
    """$VIENA_KEYS, else ~/.config/viena/keys/<car> ($XDG_CONFIG_HOME respected)."""
    if os.environ.get("VIENA_KEYS"):
        return Path(os.environ["VIENA_KEYS"]).expanduser()
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "viena" / "keys" / car


def common_name(name: str, serial: int) -> str:
    """The common name of `name`'s certificate with this serial number: NAME.TAG."""
    return f"{name}.{serial % (1 << 4 * TAG_DIGITS):0{TAG_DIGITS}x}"


def name_of(cn: str, serial: int) -> str | None:
    """The identity's name in a certificate's common name, None if it is not NAME.TAG of
    this serial number (or a bare NAME: a certificate made before tags)."""
    name, dot, _ = cn.partition(".")
    if not NAME.match(name) or (dot and cn != common_name(name, serial)):
        return None
    return name


@dataclass(frozen=True)
class Identity:
    """One certificate of the store, as read from its file (checked by `KeyStore.certificate`)."""

    name: str
    role: str
    cert: Path
    not_after: dt.datetime
    common_name: str          # what the router's access control matches (NAME.TAG)
    serial: int

    @classmethod
    def of(cls, cert, path: Path) -> Identity:
        """The certificate `cert` read from `path`; named by its common name (the whole of it
        if that is not one of `viena keys`)."""
        cn, role = subject(cert)
        return cls(name_of(cn, cert.serial_number) or cn, role, path, cert.not_valid_after_utc, cn,
                   cert.serial_number)

    @property
    def key(self) -> Path:
        """Its private key, beside the certificate (on the machine that presents it)."""
        return self.cert.with_suffix(".key")

    @property
    def legacy(self) -> bool:
        """A certificate made before tags (CN = NAME): an older one of that name would match it too."""
        return self.common_name == self.name


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

    @property
    def crl(self) -> Path:
        return self.dir / f"{CRL}.pem"

    @property
    def revoked_dir(self) -> Path:
        return self.dir / REVOKED

    def exists(self) -> bool:
        return self.ca_cert.exists()

    # -- creating -------------------------------------------------------------------------
    def init(self, router_hosts: Sequence[str] = (), force: bool = False) -> list[Identity]:
        """A new CA, its empty revocation list, the router's certificate and the standard identities."""
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes

        if self.exists() and not force:
            raise SecurityError(f"{self.ca_cert}: a CA already exists for car '{self.car}' "
                                f"(`viena keys list` shows it; --force replaces every key)")
        self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        self.dir.chmod(0o700)
        key = _new_key()
        name = _name(f"viena {self.car} CA", "ca", self.car)
        cert = (_builder(name, name, key.public_key(), CA_DAYS, x509.random_serial_number())
                .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                             content_commitment=False, key_encipherment=False,
                                             data_encipherment=False, key_agreement=False,
                                             encipher_only=False, decipher_only=False), critical=True)
                .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
                .sign(key, hashes.SHA256()))
        write_key(self.ca_key, key, force)
        write_public(self.ca_cert, cert)
        revocation.write(self.crl, key, cert)          # a new list: the old CA's means nothing now
        made = [self.issue(ROUTER_ROLE, ROUTER, router_hosts=router_hosts, force=force)]
        made += [self.issue(role, who, force=force) for who, role in STANDARD_IDENTITIES.items()]
        return made

    def issue(self, role: str, name: str, days: int | None = None, force: bool = False,
              router_hosts: Sequence[str] = (), valid_from: dt.datetime | None = None) -> Identity:
        """A certificate and key for `name` in `role`, signed by the car's CA. With `force`,
        the certificate it replaces is revoked first (reason: superseded).

        `valid_from` exists for tests that need a certificate that has already expired."""
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes

        if role not in ROLES and role != ROUTER_ROLE:
            raise SecurityError(f"unknown role '{role}' (roles: {', '.join(sorted(ROLES))})")
        if not NAME.match(name) or name in (CA, CRL) or (name == ROUTER) != (role == ROUTER_ROLE):
            raise SecurityError(f"'{name}' cannot name an identity: use lower-case letters, digits, "
                                f"- and _ (at most 32), not '{CA}' or '{CRL}', and '{ROUTER}' only "
                                f"for the router")
        if days is not None and (isinstance(days, bool) or not isinstance(days, int)
                                 or not 1 <= days <= CA_DAYS):
            raise SecurityError(f"--days {days}: a certificate lasts from 1 to {CA_DAYS} days")
        ca_key, ca_cert = self._load_ca()
        cert_path = self.cert_path(name)
        key_path = cert_path.with_suffix(".key")
        for path in (cert_path, key_path):
            if path.exists() and not force:
                raise SecurityError(f"{path}: exists; not replaced (--force replaces it and "
                                    f"revokes the old certificate)")
        if cert_path.exists():
            self._supersede(cert_path, ca_key, ca_cert)
        key = _new_key()
        days = days or (ROUTER_DAYS if role == ROUTER_ROLE else IDENTITY_DAYS)
        serial = x509.random_serial_number()
        usage = x509.oid.ExtendedKeyUsageOID
        builder = (_builder(_name(common_name(name, serial), role, self.car), ca_cert.subject,
                            key.public_key(), days, serial, valid_from)
                   .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                   .add_extension(x509.ExtendedKeyUsage([usage.SERVER_AUTH] if role == ROUTER_ROLE
                                                        else [usage.CLIENT_AUTH]), critical=False)
                   .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                                  critical=False))
        if role == ROUTER_ROLE:
            builder = builder.add_extension(
                x509.SubjectAlternativeName(_alt_names(router_hosts)), critical=False)
        write_key(key_path, key, force=True)
        cert = builder.sign(ca_key, hashes.SHA256())
        write_public(cert_path, cert)
        return Identity.of(cert, cert_path)

    def revoke(self, name: str, reason: str = "unspecified") -> Revoked:
        """Put `name`'s certificate on the revocation list, keep it under revoked/ (to name the
        entry) and delete its key. The router refuses it from its next start."""
        if reason not in REASONS:
            raise SecurityError(f"unknown reason '{reason}' (reasons: {', '.join(REASONS)})")
        ca_key, ca_cert = self._load_ca()
        cert_path = self.cert_path(name)
        if not cert_path.exists():
            earlier = [r for r in self.revocations() if r.name == name]
            if earlier:
                raise SecurityError(f"'{name}' is revoked already (serial {earlier[-1].serial:x}, "
                                    f"{earlier[-1].when:%Y-%m-%d %H:%M} UTC)")
            self.identity(name)                        # no identity 'name' (have: ...)
        cert = load_cert(cert_path)
        check_signed(cert, ca_cert, cert_path, self.ca_cert)
        entry = self._withdraw(cert_path, cert, reason, ca_key, ca_cert)
        cert_path.with_suffix(".key").unlink(missing_ok=True)
        return Revoked(entry.serial, entry.when, reason, name)

    # -- reading ----------------------------------------------------------------------------
    def identities(self) -> list[Identity]:
        """Every readable certificate in the store but the CA's, valid or not (for listing)."""
        return [Identity.of(cert, path) for path, cert in _readable(self._certificate_files())]

    def certificate(self, path: Path, crl=None) -> Identity:
        """The certificate in `path` checked as the router checks it, without any private
        key: named as its file (NAME.pem), a known role, signed by this car's CA, in date,
        not revoked. `crl` is the loaded revocation list (read from the store if None)."""
        return self._checked(path, self._load_crl() if crl is None else crl)[0]

    def client_certificates(self) -> tuple[list[Identity], list[str]]:
        """Whom the router admits, from the certificates and the revocation list alone (never
        private keys), and one line per certificate it skips, naming the file and why.
        A revocation list that is there but unusable is an error: refusing nobody would be
        the wrong way to fail."""
        self._require_store()
        crl = self._load_crl()
        admitted, skipped = [], []
        for path in self._certificate_files():
            if path.stem == ROUTER:
                continue
            try:
                ident = self.certificate(path, crl)
            except SecurityError as exc:
                skipped.append(str(exc))
                continue
            if ident.role == ROUTER_ROLE:
                skipped.append(f"{path}: a router's certificate, not a client's")
                continue
            admitted.append(ident)
        return admitted, skipped

    def client_identities(self) -> list[Identity]:
        """Every usable client certificate: what the router's access control lets in."""
        return self.client_certificates()[0]

    def identity(self, name: str) -> Identity:
        """The identity `name`, to present: its certificate checked as the router would
        (`certificate`), and its key there, private to its owner and matching. Anything else
        is a SecurityError with the fix."""
        self._require_store()
        cert_path = self.cert_path(name)
        if not cert_path.exists():
            have = ", ".join(i.name for i in self.identities()) or "none"
            raise SecurityError(f"no identity '{name}' in {self.dir} (have: {have}): "
                                f"`viena keys issue ROLE {name}` creates one")
        ident, cert = self._checked(cert_path, self._load_crl())
        key = load_key(ident.key)
        if key.public_key().public_numbers() != cert.public_key().public_numbers():
            raise SecurityError(f"{ident.key}: this key does not belong to {cert_path}: "
                                f"re-issue with `viena keys issue {ident.role} {name} --force`")
        return ident

    def router(self) -> Identity:
        ident = self.identity(ROUTER)
        if ident.role != ROUTER_ROLE:
            raise SecurityError(f"{ident.cert}: a '{ident.role}' certificate, not a router's: "
                                f"`viena keys issue router router --force` where the CA is")
        return ident

    def revocations(self) -> list[Revoked]:
        """The revocation list's entries, oldest first, each named from a copy of its
        certificate in the store (revoked/ or a stale NAME.pem) when there is one."""
        crl = self._load_crl()
        if crl is None:
            return []
        copies = _readable([*self._certificate_files(), *revocation.archived(self.revoked_dir)])
        return revocation.entries(crl, {cert.serial_number: _name_in(cert) or "" for _, cert in copies})

    # -- another machine's store ------------------------------------------------------------
    def export(self, names: list[str], target: KeyStore,
               force: bool = False) -> tuple[list[Identity], list[Identity]]:
        """What another machine runs with, into `target`: the CA certificate (never its key),
        the revocation list (and revoked/, to name its entries), `names` with their keys, and
        every other valid client certificate without its key (people: the router there admits
        them by it). Certificates the target holds without a key and this store no longer
        vouches for are removed. Returns (identities with keys, certificates alone), as the
        target reads them."""
        with_keys = [self.identity(name) for name in names]
        if self.ca_key.exists() and not self.crl.exists():
            revocation.write(self.crl, *self._load_ca())     # a store from before revocation lists
        alone = [i for i in self.client_identities() if i.name not in names]
        if target.ca_cert.exists() and target.ca_cert.read_bytes() != self.ca_cert.read_bytes() and not force:
            raise SecurityError(f"{target.ca_cert}: another CA is there (--force replaces it)")
        for ident in with_keys:
            if (target.dir / ident.key.name).exists() and not force:
                raise SecurityError(f"{target.dir / ident.key.name}: exists; not replaced (--force replaces it)")
        target.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        target.dir.chmod(0o700)
        copy_public(self.ca_cert, target.ca_cert)
        if self.crl.exists():
            copy_public(self.crl, target.crl)
        for ident in with_keys:
            write_private(target.dir / ident.key.name, ident.key.read_bytes(), force=True)
        for ident in with_keys + alone:
            copy_public(ident.cert, target.dir / ident.cert.name)
        for revoked in revocation.archived(self.revoked_dir):     # public: to name the list's entries
            target.revoked_dir.mkdir(mode=0o700, exist_ok=True)
            copy_public(revoked, target.revoked_dir / revoked.name)
        keep = {i.cert.name for i in with_keys + alone}
        for stale in target._certificate_files():
            if stale.name not in keep and not stale.with_suffix(".key").exists():
                stale.unlink()
        return ([target.identity(name) for name in names],
                [target.certificate(target.dir / i.cert.name) for i in alone])

    def cert_path(self, name: str) -> Path:
        """Where the identity `name`'s certificate is (its key beside it), checked or not."""
        return self.dir / f"{name}.pem"

    # -- internals ----------------------------------------------------------------------------

    def _certificate_files(self) -> list[Path]:
        return [p for p in sorted(self.dir.glob("*.pem")) if p.stem not in (CA, CRL)]

    def _checked(self, path: Path, crl):
        cert = load_cert(path)
        cn, role = subject(cert)
        name = name_of(cn, cert.serial_number)
        if name is None:
            raise SecurityError(f"{path}: common name '{cn}' is not NAME.SERIAL of its serial "
                                f"number {cert.serial_number:x}: not a certificate of `viena keys`")
        if name != path.stem:
            raise SecurityError(f"{path}: certificate is for '{name}', not '{path.stem}'")
        if role not in ROLES and not (role == ROUTER_ROLE and name == ROUTER):
            raise SecurityError(f"{path}: unknown role '{role}' (roles: {', '.join(sorted(ROLES))})")
        check_signed(cert, self._ca_cert_object(), path, self.ca_cert)
        reissue = f"`viena keys issue {role} {name} --force`"
        check_dates(cert, path, reissue)
        revoked = revocation.find(crl, cert.serial_number)
        if revoked is not None:
            raise SecurityError(f"{path}: revoked on {revoked.when:%Y-%m-%d %H:%M} UTC ({revoked.reason}): "
                                f"{reissue} where the CA is makes a new one")
        return Identity.of(cert, path), cert

    def _supersede(self, cert_path: Path, ca_key, ca_cert) -> None:
        """Revoke the certificate `cert_path` holds before a new one replaces it, if it is one
        of this CA's (a foreign or unreadable file has nothing to revoke)."""
        try:
            cert = load_cert(cert_path)
            check_signed(cert, ca_cert, cert_path, self.ca_cert)
        except SecurityError:
            return
        self._withdraw(cert_path, cert, "superseded", ca_key, ca_cert)

    def _withdraw(self, cert_path: Path, cert, reason: str, ca_key, ca_cert) -> Revoked:
        """`cert` (read from `cert_path`) on the revocation list, and moved to revoked/."""
        entry = revocation.add(self.crl, self._load_crl(), cert, reason, ca_key, ca_cert)
        revocation.archive(self.revoked_dir, cert_path, cert.serial_number, _name_in(cert) or cert_path.stem)
        return entry

    def _load_crl(self):
        """The revocation list, verified against the CA; None if the store has none."""
        return revocation.load(self.crl, self._ca_cert_object(), self.ca_cert) if self.crl.exists() else None

    def _require_store(self) -> None:
        if not self.ca_cert.exists():
            raise SecurityError(f"no keys for car '{self.car}' in {self.dir}: create them with "
                                f"`viena keys init --router-host ADDRESS`, or point --keys / "
                                f"VIENA_KEYS at them")

    def _ca_cert_object(self):
        self._require_store()
        cert = load_cert(self.ca_cert)
        check_dates(cert, self.ca_cert, "`viena keys init --force` (a new CA: re-issue everything)")
        return cert

    def _load_ca(self):
        cert = self._ca_cert_object()
        if not self.ca_key.exists():
            raise SecurityError(f"{self.ca_key}: missing: certificates are issued and revoked where "
                                f"the CA key is kept (then `viena keys export` carries them here)")
        return load_key(self.ca_key), cert


# -- helpers: cryptography is imported only when keys are used --------------------------------
def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ec
    return ec.generate_private_key(ec.SECP256R1())


def _name_in(cert) -> str | None:
    """The identity's name in a certificate's common name (`name_of`)."""
    return name_of(subject(cert)[0], cert.serial_number)


def _readable(paths: Iterable[Path]) -> Iterator[tuple[Path, Any]]:
    """(path, certificate) for each of `paths` that holds one."""
    for path in paths:
        try:
            yield path, load_cert(path)
        except SecurityError:
            continue


def _name(common: str, role: str, car: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"viena {car}"),
                      x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                      x509.NameAttribute(NameOID.COMMON_NAME, common)])


def _builder(subject_name, issuer, public_key, days: int, serial: int, valid_from: dt.datetime | None = None):
    from cryptography import x509
    start = valid_from or now() - dt.timedelta(minutes=5)    # small clock differences
    return (x509.CertificateBuilder().subject_name(subject_name).issuer_name(issuer)
            .public_key(public_key).serial_number(serial)
            .not_valid_before(start).not_valid_after(start + dt.timedelta(days=days)))


def _alt_names(hosts: Sequence[str]) -> list:
    """The router's names: localhost, this machine's name, and every address given."""
    from cryptography import x509
    names = ["localhost", "127.0.0.1", "::1", socket.gethostname(), f"{socket.gethostname()}.local",
             *hosts]
    out: list = []
    for host in dict.fromkeys(h for h in names if h):
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            out.append(x509.DNSName(host))
    return out
