"""The caster twin's login: the same file the client reads, made when it does not exist.

`viena up --rtk` starts the caster twin and the NTRIP client on one credentials file: the
first to need it is the caster, which writes it (mode 0600 in a 0700 folder, one line
`user:password`, a password from `secrets`) and serves that user; the client then reads
it as it reads a real caster's login. An existing file is read by the client's own rules
(services/ntrip/driver/credentials.py: refused if group or others may read it). The
password is never printed or logged.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path

from viena.services.ntrip.driver.credentials import Credentials, CredentialsError, read_credentials

__all__ = ["Credentials", "CredentialsError", "credentials_for_caster"]


def credentials_for_caster(path: str | os.PathLike, user: str = "viena") -> tuple[Credentials, bool]:
    """The login in `path`, and whether it was made now (for `user`, a new random password)."""
    path = Path(path).expanduser()
    if ":" in user or not user:
        raise CredentialsError(f"a caster user name is not empty and has no colon, not {user!r}")
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return read_credentials(path), False
    except OSError as exc:
        raise CredentialsError(f"credentials file {path} cannot be made: {exc.strerror}") from None
    password = secrets.token_urlsafe(18)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f"{user}:{password}\n")
    return Credentials(user, password), True
