"""`viena keys`: the car's certificate authority and the identities it vouches for.

    viena keys init [--router-host ADDRESS ...]     a CA, the router's certificate, and one
                                                   identity per process and role
    viena keys issue ROLE NAME [--days N]          a person or laptop: `issue pilot alice`
                                                   (--force re-issues and revokes the old one)
    viena keys revoke NAME [--reason R]            put NAME's certificate on the CA's revocation list
    viena keys list                                what exists, its role, expiry, what is revoked
    viena keys export NAME ... -o DIR              another machine's store: these identities with
                                                   their keys, every other certificate without
                                                   one, the revocation list (never the CA key)
    viena keys roles                               what each role may do
    viena keys zenoh-config NAME [--connect EP]    a zenoh config for the `zenoh` CLI

Keys live in --keys DIR, else $VIENA_KEYS, else ~/.config/viena/keys/<car>/. Private keys
are written with mode 0600, never printed, and never replaced without --force. The router
reads its access control from this directory's certificates and revocation list when it
starts (zenoh cannot reload access control live): after issuing, re-issuing or revoking a
certificate, carry the store to the car (`export`) and restart the router (`viena restart
router`, or `viena down` and `up`).
"""
from __future__ import annotations

import argparse
import datetime as dt
import sys

from viena.common.access import ROLES, describe
from viena.common.errors import ConfigError
from viena.common.keys import DEFAULT_CAR
from viena.common.keystore import (
    CA_DAYS,
    EXPIRY_WARNING,
    ROUTER,
    ROUTER_ROLE,
    Identity,
    KeyStore,
    SecurityError,
)
from viena.common.revocation import REASONS
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
    p.add_argument("--days", type=int, default=None,
                   help=f"validity, 1 to {CA_DAYS} (default 365; router 1825)")
    p.add_argument("--router-host", action="append", default=[], metavar="NAME_OR_IP",
                   help="for the router: its addresses")
    p.add_argument("--force", action="store_true",
                   help="replace an existing identity of that name (its old certificate is revoked)")
    p.set_defaults(keys_func=_issue)

    p = cmds.add_parser("revoke", help="revoke an identity's certificate (the router refuses it "
                                       "from its next start)")
    p.add_argument("name", help="the identity (alice, ...)")
    p.add_argument("--reason", choices=REASONS, default="unspecified", help="why (default unspecified)")
    p.set_defaults(keys_func=_revoke)

    p = cmds.add_parser("export", help="another machine's key store: these identities with their "
                                       "keys, the other certificates without, the revocation list")
    p.add_argument("names", nargs="+", metavar="NAME", help="the identities that machine runs")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="the other machine's key store")
    p.add_argument("--force", action="store_true", help="replace what is there")
    p.set_defaults(keys_func=_export)

    p = cmds.add_parser("list", help="the identities, their roles and expiry, and what is revoked")
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
    print(f"\nKeep {store.ca_key} on this machine, never on the car: whoever holds it can make "
          f"identities. The car's store is `viena keys export {' '.join(CAR_IDENTITIES)} -o DIR`.")
    return 0


#: what the Pi runs (compose/pi.conf): the router and the car's own processes
CAR_IDENTITIES = ("router", "gnss0", "gnss1", "razor0", "steering", "estimator", "autopilot", "recorder")
RESTART = ("zenoh reads access control only when the router starts: carry the store to the car "
           "(`viena keys export ... --force`) and restart the router there (`viena restart router`)")


def _issue(store: KeyStore, args) -> int:
    before = {r.serial for r in store.revocations()} if store.exists() else set()
    ident = store.issue(args.role, args.name, days=args.days, force=args.force,
                        router_hosts=args.router_host)
    print(f"issued '{ident.name}' ({ident.role}) until {ident.not_after:%Y-%m-%d}, common name "
          f"{ident.common_name}: {ident.cert}, {ident.key}")
    for old in (r for r in store.revocations() if r.serial not in before):
        print(f"revoked its previous certificate (serial {old.serial:x}) in {store.crl}")
    if ident.role != ROUTER_ROLE:
        print(f"The router admits it from its next start; {RESTART}.")
    return 0


def _revoke(store: KeyStore, args) -> int:
    entry = store.revoke(args.name, args.reason)
    print(f"revoked '{entry.name}' (serial {entry.serial:x}, {entry.reason}) in {store.crl}; "
          f"its key is deleted, its certificate kept in {store.revoked_dir}")
    if args.name == ROUTER:
        print("zenoh clients read no revocation list: a router key that got out needs a new CA "
              "(`viena keys init --force`)")
    else:
        print(f"The router refuses it from its next start; {RESTART}.")
    return 0


def _export(store: KeyStore, args) -> int:
    target = KeyStore(args.output, store.car)
    with_keys, alone = store.export(args.names, target, force=args.force)
    revoked = len(target.revocations())
    print(f"{target.dir}: ca.pem (not its key), crl.pem ({revoked} revoked), "
          f"{', '.join(i.name for i in with_keys)} with their keys, "
          f"{', '.join(i.name for i in alone) or 'no one'} by certificate alone")
    print(f"Carry it to the other machine's ~/.config/viena/keys/{store.car}/ (or its VIENA_KEYS) "
          f"and restart its router.")
    return 0


def _list(store: KeyStore, args) -> int:
    if not store.exists():
        raise SecurityError(f"no keys for car '{store.car}' in {store.dir}: `viena keys init` creates them")
    print(f"car '{store.car}', keys in {store.dir}")
    _print_table(store.identities(), store)
    revoked = store.revocations()
    if not store.crl.exists():
        print(f"\nno revocation list ({store.crl}): nothing is revoked")
        return 0
    print(f"\nrevoked ({store.crl}, {len(revoked)}): the router refuses these from its next start")
    if revoked:
        print(f"{'name':<12} {'serial':<40} {'revoked (UTC)':<17} reason")
    for entry in revoked:
        print(f"{entry.name or '?':<12} {entry.serial:<40x} {entry.when:%Y-%m-%d %H:%M} {entry.reason}")
    return 0


def _print_table(identities: list[Identity], store: KeyStore | None = None) -> None:
    print(f"{'name':<12} {'role':<10} {'expires':<11} {'common name':<29} status")
    for ident in identities:
        status = _status(ident, store) if store is not None else "ok"
        print(f"{ident.name:<12} {ident.role:<10} {ident.not_after:%Y-%m-%d}  {ident.common_name:<29} {status}")


def _status(ident: Identity, store: KeyStore) -> str:
    """What the router makes of this certificate, and whether this machine can present it."""
    now = dt.datetime.now(dt.UTC)
    try:
        store.certificate(ident.cert)
        if ident.key.exists() or ident.name == ROUTER:
            store.identity(ident.name)
    except SecurityError as exc:
        return str(exc)
    if ident.not_after - now < EXPIRY_WARNING:
        return f"expires in {(ident.not_after - now).days} days: re-issue soon"
    if ident.legacy:
        return (f"ok, but made before tagged common names: re-issue (`viena keys issue {ident.role} "
                f"{ident.name} --force`) so that no older certificate of '{ident.name}' passes for it")
    return "ok" if ident.key.exists() else "ok (certificate alone: its key is elsewhere)"


def _roles(store: KeyStore, args) -> int:
    for name, role in ROLES.items():
        print(f"{name:<10} {role.summary}\n{'':<10} {describe(name)}")
    return 0


def _zenoh_config(store: KeyStore, args) -> int:
    sys.stdout.write(client_config_json5(store, args.name, args.connect or [_running_endpoint()]))
    return 0


def _running_endpoint() -> str:
    """The running profile's TLS endpoint, so the printed config reaches the car as it is."""
    from viena.common.runstate import read_environment, running_profiles

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
