"""`viena keys`: the car's certificate authority and the identities it vouches for.

    viena keys init [--router-host ADDRESS ...]     a CA, the router's certificate, and one
                                                   identity per process and role
    viena keys issue ROLE NAME [--days N]          a person or laptop: `issue pilot alice`
    viena keys list                                what exists, its role and when it expires
    viena keys export NAME ... -o DIR              identities for another machine (no CA key)
    viena keys roles                               what each role may do
    viena keys zenoh-config NAME [--connect EP]    a zenoh config for the `zenoh` CLI

Keys live in --keys DIR, else $VIENA_KEYS, else ~/.config/viena/keys/<car>/. Private keys
are written with mode 0600, never printed, and never replaced without --force. The router
reads its access control from this directory when it starts: after issuing or replacing
a certificate, restart the router (`viena restart router`, or `viena down` and `up`).
"""
from __future__ import annotations

import argparse
import datetime as dt
import sys

from viena.common.access import ROLES, describe
from viena.common.errors import ConfigError
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import EXPIRY_WARNING, ROUTER_ROLE, KeyStore, SecurityError
from viena.common.secure import client_config_json5


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena keys", description=__doc__)
    parser.add_argument("--car", default=DEFAULT_CAR, help=f"whose keys (default {DEFAULT_CAR})")
    parser.add_argument("--keys", "--dir", dest="keys", metavar="DIR",
                        help="the key store (default $VIENA_KEYS, else ~/.config/viena/keys/CAR)")
    cmds = parser.add_subparsers(dest="keys_command", required=True, metavar="COMMAND")

    p = cmds.add_parser("init", help="create the car's CA, the router's certificate and the standard identities")
    p.add_argument("--router-host", action="append", default=[], metavar="NAME_OR_IP",
                   help="an address clients use to reach the router (the Pi's Wi-Fi address or "
                        "hostname); repeatable. localhost and this machine's name are always in.")
    p.add_argument("--force", action="store_true", help="replace existing keys (every identity must be re-issued)")
    p.set_defaults(keys_func=_init)

    p = cmds.add_parser("issue", help="a certificate for a person, laptop or process")
    p.add_argument("role", help=f"one of: {', '.join(sorted(ROLES))} (or router)")
    p.add_argument("name", help="the identity's name: a person (alice), a unit (gnss2), ...")
    p.add_argument("--days", type=int, default=None, help="validity (default 365; router 1825)")
    p.add_argument("--router-host", action="append", default=[], metavar="NAME_OR_IP",
                   help="for the router: its addresses")
    p.add_argument("--force", action="store_true", help="replace an existing identity of that name")
    p.set_defaults(keys_func=_issue)

    p = cmds.add_parser("export", help="copy identities (and the CA certificate, never its key) "
                                       "to a directory, for another machine")
    p.add_argument("names", nargs="+", metavar="NAME")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="the other machine's key store")
    p.add_argument("--force", action="store_true", help="replace what is there")
    p.set_defaults(keys_func=_export)

    p = cmds.add_parser("list", help="the identities, their roles and expiry")
    p.set_defaults(keys_func=_list)

    p = cmds.add_parser("roles", help="what each role may do")
    p.set_defaults(keys_func=_roles)

    p = cmds.add_parser("zenoh-config", help="a zenoh JSON5 config presenting one identity")
    p.add_argument("name", help="the identity (pilot, observer, alice, ...)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="the router (default: the running profile's, else tls/localhost:7447)")
    p.set_defaults(keys_func=_zenoh_config)
    return parser


def run(args: argparse.Namespace) -> int:
    store = KeyStore.for_car(args.car, args.keys)
    try:
        return args.keys_func(store, args) or 0
    except ConfigError as exc:
        print(f"viena keys: {exc}", file=sys.stderr)
        return 2


def _init(store: KeyStore, args) -> int:
    made = store.init(args.router_host, force=args.force)
    print(f"car '{store.car}': CA and {len(made)} identities in {store.dir}")
    _print_table(made)
    print(f"\nKeep {store.ca_key} safe (off the car once everything is issued): whoever holds it "
          f"can make identities.")
    return 0


def _issue(store: KeyStore, args) -> int:
    ident = store.issue(args.role, args.name, days=args.days, force=args.force,
                        router_hosts=args.router_host)
    print(f"issued '{ident.name}' ({ident.role}) until {ident.not_after:%Y-%m-%d}: {ident.cert}, {ident.key}")
    if ident.role != ROUTER_ROLE:
        print("The router admits it once restarted (`viena restart router`, or down and up).")
    return 0


def _export(store: KeyStore, args) -> int:
    target = KeyStore(args.output, store.car)
    done = store.export(args.names, target, force=args.force)
    print(f"{', '.join(i.name for i in done)} and the CA certificate copied to {target.dir}; "
          f"carry it to the other machine's ~/.config/viena/keys/{store.car}/ (or its VIENA_KEYS)")
    return 0


def _list(store: KeyStore, args) -> int:
    if not store.exists():
        raise SecurityError(f"no keys for car '{store.car}' in {store.dir}: `viena keys init` creates them")
    print(f"car '{store.car}', keys in {store.dir}")
    _print_table(store.identities(), store)
    return 0


def _print_table(identities, store: KeyStore | None = None) -> None:
    now = dt.datetime.now(dt.UTC)
    print(f"{'name':<12} {'role':<10} {'expires':<11} status")
    for ident in identities:
        status = "ok"
        if store is not None:
            try:
                store.identity(ident.name)
            except SecurityError as exc:
                status = str(exc)
        if status == "ok" and ident.not_after - now < EXPIRY_WARNING:
            status = f"expires in {(ident.not_after - now).days} days: re-issue soon"
        print(f"{ident.name:<12} {ident.role:<10} {ident.not_after:%Y-%m-%d}  {status}")


def _roles(store: KeyStore, args) -> int:
    for name, role in ROLES.items():
        print(f"{name:<10} {role.summary}\n{'':<10} {describe(name)}")
    return 0


def _zenoh_config(store: KeyStore, args) -> int:
    sys.stdout.write(client_config_json5(store, args.name, args.connect or [_running_endpoint()]))
    return 0


def _running_endpoint() -> str:
    """The running profile's TLS endpoint, so the printed config reaches the car as it is."""
    from viena.runstate import read_environment, running_profiles

    for profile in running_profiles():
        env = read_environment(profile) or {}
        tls = [e for e in env.get("VIENA_CONNECT", "").split(",") if e.startswith("tls/")]
        if tls:
            return tls[0]
    return "tls/localhost:7447"


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
