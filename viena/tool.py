"""What every laptop tool (sub, record, replay, monitor, list, hz) does the same way: read
its settings and connection flags, connect or give up in one line, check the key
expressions a person typed, and say so when nothing arrives.

A tool's `run(args)` returns `guarded("viena sub", body, args)`: a `Fail` raised anywhere
in `body` becomes one line on stderr and the exit status (2 for bad input, 1 when the
car cannot be reached or nothing came), never a traceback.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable

from viena.common.errors import InputError
from viena.common.keys import Keys
from viena.common.log import setup_logging
from viena.common.session import Unreachable, car_name, check_keyexpr, load_settings_file, open_session, zenoh_config

#: how long a subscription may hear nothing before the tool says so
SILENCE_WARNING_S = 5.0
#: how long a tool tries to reach the router before it gives up (--timeout)
CONNECT_TIMEOUT_S = 10.0


class Fail(Exception):
    """A tool's failure: one line for the person, and the exit status."""

    def __init__(self, message: str, status: int = 1):
        super().__init__(message)
        self.status = status


def guarded(prog: str, body: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    try:
        return body(args)
    except Fail as exc:
        print(f"{prog}: {exc}", file=sys.stderr, flush=True)
        return exc.status


def tool_logging(args: argparse.Namespace) -> None:
    """A tool's output is what it prints: the default level (INFO) logs warnings only, so
    the session's own INFO lines never mix with it; --log-level DEBUG still shows all."""
    setup_logging("WARNING" if args.log_level == "INFO" else args.log_level)


def add_timeout_flag(parser: argparse.ArgumentParser, default_s: float = CONNECT_TIMEOUT_S) -> None:
    parser.add_argument("--timeout", type=float, default=default_s, metavar="S",
                        help=f"give up if the router cannot be reached in S seconds "
                             f"(default {default_s:g}; 0 waits for ever)")


class Connection:
    """A tool's settings, car and zenoh config, from its flags; bad input is a Fail(2)."""

    def __init__(self, args: argparse.Namespace, identity: str | None = None):
        try:
            self.toml = load_settings_file(args)
            self.car = car_name(args, self.toml)
            self.keys = Keys(self.car)
            self.conf = zenoh_config(args, self.toml, identity=identity)
        except (InputError, ValueError) as exc:
            raise Fail(str(exc), 2) from None

    def open(self, stop: threading.Event, timeout_s: float | None, on_wait=None):
        """The session; None if stopped first; Fail(1) naming the endpoint after timeout_s."""
        try:
            return open_session(self.conf, stop, timeout_s=timeout_s or None, on_wait=on_wait)
        except Unreachable as exc:
            raise Fail(str(exc), 1) from None


def key_expressions(values: list[str]) -> list[str]:
    """The key expressions a person typed, each checked; Fail(2) on the first bad one."""
    try:
        return [check_keyexpr(v) for v in values]
    except InputError as exc:
        raise Fail(str(exc), 2) from None


class SilenceWarning:
    """Says once, on stderr, that nothing has matched the key expressions for a while: a
    misspelt key is otherwise silence. `heard()` from any thread; `check()` from the loop."""

    def __init__(self, prog: str, keyexprs: list[str], after_s: float = SILENCE_WARNING_S):
        self.prog, self.keyexprs, self.after_s = prog, keyexprs, after_s
        self.since = time.monotonic()
        self.any = False
        self.said = False

    def heard(self) -> None:
        self.any = True

    def check(self) -> None:
        if self.any or self.said or time.monotonic() - self.since < self.after_s:
            return
        self.said = True
        keys = ", ".join(f"'{k}'" for k in self.keyexprs)
        print(f"{self.prog}: nothing on {keys} for {self.after_s:g} s: is the key right? "
              f"`viena list` shows what the car publishes", file=sys.stderr, flush=True)


def add_drive_arguments(parser: argparse.ArgumentParser) -> None:
    """The recording a tool reads (see `open_source`), as `file` and `drive`."""
    parser.add_argument("file", metavar="RECORDING",
                        help="one MCAP file (read alone), or a drive of several files read as one: "
                             "its directory or its id (viena-YYYYMMDD-HHMMSS)")
    parser.add_argument("--drive", metavar="ID",
                        help="with a directory of several drives: which one (default the newest)")
