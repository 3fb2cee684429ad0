"""`viena router`: a zenoh session in router mode, for machines without zenohd.

It reads the same JSON5 file zenohd would (compose/zenoh/router.json5), so a user with
zenohd can run `zenohd -c compose/zenoh/router.json5` instead.
"""
from __future__ import annotations

import argparse
import logging
import sys

from viena.common.config import ConfigError, load_zenoh_config
from viena.common.log import setup_logging
from viena.common.session import stop_on_signals
from viena.paths import router_config

log = logging.getLogger("viena.router")


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena router", description=__doc__)
    parser.add_argument("--listen", metavar="ENDPOINT", action="append",
                        help="where to listen, e.g. tcp/0.0.0.0:7447 (repeatable; "
                             "default: the config file's listen endpoints)")
    parser.add_argument("--connect", metavar="ENDPOINT", action="append",
                        help="another router to join (repeatable)")
    parser.add_argument("--config", metavar="FILE", default=None,
                        help=f"zenoh JSON5 config (default {router_config()})")
    parser.add_argument("--log-level", default="INFO", metavar="LEVEL")
    return parser


def run(args: argparse.Namespace) -> int:
    import zenoh

    setup_logging(args.log_level)
    path = args.config or router_config()
    try:
        conf = load_zenoh_config(path, mode="router", listen=args.listen, connect=args.connect)
    except ConfigError as exc:
        print(f"viena router: config error: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        print(f"viena router: cannot start: {str(exc).split(' at ')[0]}", file=sys.stderr)
        return 1
    listening = [str(loc) for loc in session.info.locators()] if hasattr(session.info, "locators") else args.listen
    log.info("router %s listening on %s (config %s)", session.zid(), listening or "config endpoints", path)
    stop.wait()
    session.close()
    log.info("router stopped")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
