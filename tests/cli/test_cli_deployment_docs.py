"""The deployment guide (docs/deployment.md and the README's "Running on the car") is followed
by people without reading code (issue 14), so what it tells them to type must be what the
code accepts, and the device names it makes must be those the `pi` profile opens."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from viena import cli

REPO = Path(__file__).resolve().parents[2]
GUIDE = REPO / "docs" / "deployment.md"
#: `viena ...` on a line of a code block (plain or through sudo and the virtualenv), up to a comment
BLOCK_COMMAND = re.compile(r"^ {4,}(?:sudo )?(?:~/viena/bin/)?viena ([a-z][^#\n]*)", re.M)
#: ... or inline, with a flag (a bare `viena keys export` names a command, it is not one to type)
INLINE_COMMAND = re.compile(r"`(?:sudo )?(?:~/viena/bin/)?viena ([a-z][^`]* --[^`]*)`")


def readme_section() -> str:
    text = (REPO / "README.md").read_text()
    start = text.index("## Running on the car\n")
    return text[start:text.index("\n## ", start + 1)]


def commands(text: str) -> list[str]:
    found = [*BLOCK_COMMAND.finditer(text), *INLINE_COMMAND.finditer(text)]
    return sorted({m.group(1).strip() for m in found})


@pytest.mark.parametrize("where", ["docs/deployment.md", "README.md"])
def test_every_viena_command_of_the_guide_parses(where, capsys):
    text = GUIDE.read_text() if where == "docs/deployment.md" else readme_section()
    found = commands(text)
    assert {c.split()[0] for c in found} >= {"service", "doctor", "keys"}, found
    parser = cli.build_parser()
    for command in found:
        argv = shlex.split(command.replace("$USER", "pi"))
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"{where}: `viena {command}` does not parse: {capsys.readouterr().err.strip()} ({exc})")


def test_the_guides_device_names_are_the_pi_profiles():
    text = (REPO / "compose" / "pi.toml").read_text()
    defaults = dict(re.findall(r"\$\{(VIENA_[A-Z0-9]+_DEVICE):-([^}]+)\}", text))
    assert defaults == {"VIENA_GNSS0_DEVICE": "/dev/viena-gnss0", "VIENA_GNSS1_DEVICE": "/dev/viena-gnss1",
                        "VIENA_RAZOR0_DEVICE": "/dev/viena-razor0"}
    guide = GUIDE.read_text()
    for variable, device in defaults.items():
        assert f"| `{device}` | `{variable}` |" in guide                       # the table
        assert f'SYMLINK+="{device.removeprefix("/dev/")}"' in guide           # the udev rule that makes it
        assert device in readme_section()
    assert "bitrate = 1000000" in text and "BitRate=1M" in guide and "BitRate=1M" in readme_section()
