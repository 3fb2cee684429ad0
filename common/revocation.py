"""The car's revocation list: the certificates its CA has withdrawn before they expire.

The router cannot check revocation itself: zenoh's TLS reads no certificate revocation list.
So the key store keeps one, an X.509 CRL signed by the car's CA (`crl.pem`, public, carried
to the car by `viena keys export`), and the router leaves every certificate on it out of its
access control (`KeyStore.client_certificates`, common/secure.py). Revoking takes the CA key,
so it happens where the CA is kept. A CRL holds serial numbers only: each revoked certificate
is kept under `revoked/` as NAME.SERIAL.pem, so that its entry can be named.
"""
from __future__ import annotations

import datetime as dt
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from viena.common.x509util import SecurityError, now, write_public

#: why a certificate is revoked: RFC 5280's reasons, as `viena keys revoke --reason` spells them
REASONS = ("unspecified", "key-compromise", "affiliation-changed", "superseded",
           "cessation-of-operation", "privilege-withdrawn")


@dataclass(frozen=True)
class Revoked:
    """One entry of the revocation list; `name` is "" when no copy of the certificate is at hand."""

    serial: int
    when: dt.datetime
    reason: str
    name: str = ""


def load(path: Path, ca_cert, ca_path: Path):
    """The revocation list in `path`, verified against the CA's certificate (read from `ca_path`)."""
    from cryptography import x509

    fix = "copy it again from where the CA is kept (`viena keys export ... --force`)"
    try:
        crl = x509.load_pem_x509_crl(path.read_bytes())
    except (ValueError, OSError):
        raise SecurityError(f"{path}: not a PEM revocation list: {fix}") from None
    if crl.issuer != ca_cert.subject or not crl.is_signature_valid(ca_cert.public_key()):
        raise SecurityError(f"{path}: not signed by this car's CA ({ca_path}): {fix}")
    return crl


def write(path: Path, ca_key, ca_cert, old=None, new: Sequence = ()) -> None:
    """The list, signed by the CA: the entries of `old` (the list as loaded, None for a new
    one) and `new`, numbered one past `old`."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    number = 0 if old is None else old.extensions.get_extension_for_class(x509.CRLNumber).value.crl_number
    builder = (x509.CertificateRevocationListBuilder().issuer_name(ca_cert.subject)
               .last_update(now()).next_update(ca_cert.not_valid_after_utc)
               .add_extension(x509.CRLNumber(number + 1), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                              critical=False))
    for entry in [*(old or []), *new]:
        builder = builder.add_revoked_certificate(entry)
    write_public(path, builder.sign(ca_key, hashes.SHA256()))


def add(path: Path, crl, cert, reason: str, ca_key, ca_cert) -> Revoked:
    """`cert` put on the list `crl` (loaded from `path`; None if there is none) and the list
    written anew; a certificate on it already keeps its entry."""
    from cryptography import x509

    known = find(crl, cert.serial_number)
    if known is not None:
        return known
    entry = x509.RevokedCertificateBuilder().serial_number(cert.serial_number).revocation_date(now())
    if reason != "unspecified":                   # RFC 5280: omit rather than say unspecified
        entry = entry.add_extension(x509.CRLReason(x509.ReasonFlags[reason.replace("-", "_")]),
                                    critical=False)
    revoked = entry.build()
    write(path, ca_key, ca_cert, crl, [revoked])
    return _record(revoked)


def find(crl, serial: int) -> Revoked | None:
    """The list's entry for this serial number; None if it has none (or there is no list)."""
    entry = None if crl is None else crl.get_revoked_certificate_by_serial_number(serial)
    return None if entry is None else _record(entry)


def entries(crl, names: Mapping[int, str]) -> list[Revoked]:
    """The list's entries, oldest first, named from `names` (serial number: name)."""
    return sorted((_record(r, names.get(r.serial_number, "")) for r in crl), key=lambda r: r.when)


def archive(directory: Path, cert_path: Path, serial: int, name: str) -> None:
    """Move a revoked certificate to `directory` (revoked/) as NAME.SERIAL.pem."""
    directory.mkdir(mode=0o700, exist_ok=True)
    os.replace(cert_path, directory / f"{name}.{serial:x}.pem")


def archived(directory: Path) -> list[Path]:
    """The revoked certificates kept in `directory`."""
    return sorted(directory.glob("*.pem"))


def _record(entry, name: str = "") -> Revoked:
    return Revoked(entry.serial_number, entry.revocation_date_utc, _reason(entry), name)


def _reason(entry) -> str:
    """A CRL entry's reason, spelled as `viena keys revoke --reason` takes it."""
    from cryptography import x509

    try:
        flag = entry.extensions.get_extension_for_class(x509.CRLReason).value.reason
    except x509.ExtensionNotFound:
        return "unspecified"
    return flag.name.replace("_", "-")
