"""The certificate and key files of a key store, read, written and checked; below both the
store (common/keystore.py) and its revocation list (common/revocation.py), which share them.

Private keys are written with mode 0600 from their first byte; public files (certificates,
the revocation list) are replaced whole, so a reader never sees half of one. Every problem is
a `SecurityError` whose one line names the file and the fix. cryptography is imported only
when keys are used: a car without security never loads it.
"""
from __future__ import annotations

import datetime as dt
import os
import stat
from pathlib import Path

from viena.common.errors import ConfigError


class SecurityError(ConfigError):
    """Keys that cannot be used: missing, expired, foreign, revoked, loose permissions, bad role."""


def now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def subject(cert) -> tuple[str, str]:
    """A certificate's (common name, organizational unit): its (NAME.TAG, role)."""
    from cryptography.x509.oid import NameOID

    def first(attr) -> str:
        values = cert.subject.get_attributes_for_oid(attr)
        return str(values[0].value) if values else ""
    return first(NameOID.COMMON_NAME), first(NameOID.ORGANIZATIONAL_UNIT_NAME)


def load_cert(path: Path):
    from cryptography import x509
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except FileNotFoundError:
        raise SecurityError(f"{path}: missing") from None
    except OSError as exc:
        raise SecurityError(f"{path}: cannot be read ({exc.strerror})") from None
    except ValueError:
        raise SecurityError(f"{path}: not a PEM certificate") from None


def load_key(path: Path):
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


def check_dates(cert, path: Path, fix: str) -> None:
    at = now()
    if at < cert.not_valid_before_utc:
        raise SecurityError(f"{path}: not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC "
                            f"(is this machine's clock right?)")
    if at >= cert.not_valid_after_utc:
        raise SecurityError(f"{path}: expired on {cert.not_valid_after_utc:%Y-%m-%d}: re-issue with {fix}")


def check_signed(cert, ca_cert, path: Path, ca_path: Path) -> None:
    try:
        cert.verify_directly_issued_by(ca_cert)
    except Exception:
        raise SecurityError(f"{path}: not signed by this car's CA ({ca_path}): it belongs to "
                            f"another car or another key store; issue it here") from None


def write_key(path: Path, key, force: bool) -> None:
    from cryptography.hazmat.primitives import serialization
    write_private(path, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                          serialization.NoEncryption()), force)


def write_private(path: Path, data: bytes, force: bool) -> None:
    """0600 from the first byte; an existing file is an error unless `force`."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    try:
        fd = os.open(path, flags, 0o600)
    except FileExistsError:
        raise SecurityError(f"{path}: exists; not replaced (--force replaces it)") from None
    with os.fdopen(fd, "wb") as f:
        os.fchmod(f.fileno(), 0o600)
        f.write(data)


def write_public(path: Path, signed) -> None:
    """A certificate or revocation list, as PEM."""
    from cryptography.hazmat.primitives import serialization
    replace_public(path, signed.public_bytes(serialization.Encoding.PEM))


def copy_public(source: Path, target: Path) -> None:
    replace_public(target, source.read_bytes())


def replace_public(path: Path, data: bytes) -> None:
    """A public file (certificate, CRL), mode 0644, replaced whole: a reader never sees half."""
    partial = path.with_name(f".{path.name}.partial")
    partial.write_bytes(data)
    partial.chmod(0o644)
    os.replace(partial, path)
