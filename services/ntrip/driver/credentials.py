"""The caster login, from a file only its owner can read (as ssh treats private keys).

The file holds one line, ``user:password`` (the password may hold colons; the user may
not, as in HTTP Basic authentication); blank lines and lines starting with ``#`` are
skipped. It is refused, with one line saying how to fix it, when group or others may
read it, it belongs to another user, or it is a symlink (the file is checked as opened, so
it cannot be swapped between the check and the read). Nothing here ever puts the password, or the file's
content, into a message: errors name the file and what is wrong with it only.
"""
from __future__ import annotations

import errno
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path


class CredentialsError(ValueError):
    """The credentials file cannot be used: one line for a person."""


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str = field(repr=False)

    def __str__(self) -> str:
        return f"{self.user}:***"


def default_path(car: str) -> Path:
    return Path.home() / ".config" / "viena" / "ntrip" / f"{car}.credentials"


def read_credentials(path: str | os.PathLike) -> Credentials:
    """The login in `path`, checked as the module docstring says. The checks are made on
    the file opened (fstat), not on its name, and a symlink is not followed: nothing can
    swap the file between the check and the read."""
    path = Path(path).expanduser()
    try:
        # O_NONBLOCK: a FIFO put there must be refused, not wait for a writer
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    except FileNotFoundError:
        raise CredentialsError(f"credentials file {path} does not exist: write one line user:password "
                               f"into it and chmod 600 it") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise CredentialsError(f"credentials file {path} is a symlink: give the file itself") from None
        raise CredentialsError(f"credentials file {path}: {exc.strerror}") from None
    try:
        _check(path, os.fstat(fd))
    except BaseException:
        os.close(fd)
        raise
    with os.fdopen(fd, encoding="utf-8", newline="") as file:
        try:
            text = file.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise CredentialsError(f"credentials file {path} cannot be read ({type(exc).__name__})") from None
    return _parse(path, text)


def _check(path: Path, st: os.stat_result) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise CredentialsError(f"credentials file {path} is not a file")
    if st.st_mode & 0o077:
        raise CredentialsError(f"credentials file {path} is open to group or others (mode "
                               f"{stat.S_IMODE(st.st_mode):04o}): chmod 600 {path}")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise CredentialsError(f"credentials file {path} belongs to another user (uid {st.st_uid})")


def _parse(path: Path, text: str) -> Credentials:
    """The one login line. Only the line's end (CR LF or LF) is cut from the password:
    spaces at its ends are part of it; the user part loses the spaces around it."""
    lines = [line.rstrip("\r\n") for line in text.split("\n")]
    lines = [line for line in lines if line.strip() and not line.strip().startswith("#")]
    if len(lines) != 1 or ":" not in lines[0] or lines[0].lstrip().startswith(":"):
        raise CredentialsError(f"credentials file {path} must hold one line user:password")
    user, password = lines[0].split(":", 1)
    return Credentials(user.strip(), password)
