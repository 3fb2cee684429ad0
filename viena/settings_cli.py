"""`viena settings [SERVICE ...]`: every setting of a service, its type, default and meaning.

    viena settings gnss          the [gnss] table's settings, as Markdown
    viena settings imu --toml    the same as a TOML table to copy into a profile
    viena settings --check       exit 1 if a services/<name>/README.md table is out of date
    viena settings --write       rewrite those tables from the settings dataclasses

Each service declares its settings once, as a dataclass (common/settings.py); the tables
in its README sit between two markers and are made from that dataclass, never by hand.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import inspect
import pkgutil
import sys
from pathlib import Path

import viena.services
from viena.common.service import Service
from viena.common.settings import markdown, toml_table

BEGIN = "<!-- settings: made by `viena settings --write` from the dataclass; edit that, not this -->"
END = "<!-- settings: end -->"


def services() -> dict[str, type[Service]]:
    """Every service, by name: the Service class in each services/<name>/service.py."""
    found = {}
    for info in pkgutil.iter_modules(viena.services.__path__):
        name = f"viena.services.{info.name}.service"
        if info.ispkg and importlib.util.find_spec(name) is not None:
            module = importlib.import_module(name)
            for value in vars(module).values():
                if isinstance(value, type) and issubclass(value, Service) and value.__module__ == name:
                    found[value.name] = value
    return dict(sorted(found.items()))


def readme_path(cls: type[Service]) -> Path:
    return Path(inspect.getfile(cls)).resolve().parent / "README.md"


def with_table(text: str, cls: type[Service]) -> str:
    """The README's text with the table between the markers made anew."""
    head, begin, rest = text.partition(BEGIN)
    _, end, tail = rest.partition(END)
    if not begin or not end:
        raise ValueError("no settings section: put the two markers of viena/settings_cli.py where it goes")
    return f"{head}{BEGIN}\n\n{markdown(cls.settings_class)}\n{END}{tail}"


def stale_readmes(chosen: list[type[Service]]) -> list[str]:
    """The READMEs whose settings table is not what the dataclass makes, and why."""
    stale = []
    for cls in chosen:
        path = readme_path(cls)
        try:
            text = path.read_text()
            if with_table(text, cls) != text:
                stale.append(f"{path}: out of date")
        except (OSError, ValueError) as exc:
            stale.append(f"{path}: {exc}")
    return stale


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena settings", description=__doc__)
    parser.add_argument("services", nargs="*", metavar="SERVICE", help="which services (default all)")
    how = parser.add_mutually_exclusive_group()
    how.add_argument("--toml", action="store_true", help="print TOML tables of the defaults")
    how.add_argument("--check", action="store_true", help="exit 1 if a README's table is out of date")
    how.add_argument("--write", action="store_true", help="rewrite the READMEs' tables")
    return parser


def run(args: argparse.Namespace) -> int:
    known = services()
    unknown = [name for name in args.services if name not in known]
    if unknown:
        print(f"viena settings: no service {unknown[0]!r} (have {', '.join(known)})", file=sys.stderr)
        return 2
    chosen = [known[name] for name in args.services or known]
    if args.check:
        stale = stale_readmes(chosen)
        for line in stale:
            print(f"{line}: run `viena settings --write`", file=sys.stderr)
        return 1 if stale else 0
    if args.write:
        for cls in chosen:
            path = readme_path(cls)
            try:
                path.write_text(with_table(path.read_text(), cls))
            except (OSError, ValueError) as exc:
                print(f"viena settings: {path}: {exc}", file=sys.stderr)
                return 1
            print(f"wrote {path}")
        return 0
    for cls in chosen:
        if args.toml:
            print(toml_table(cls.settings_class, cls.name))
        else:
            print(f"## [{cls.name}]\n\n{markdown(cls.settings_class)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
