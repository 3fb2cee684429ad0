"""The same flags everywhere (issue 14): every command answers --version, every process and
laptop tool takes the same connection flags, --unit exists only where units do, and one
name means one thing (--baudrate, --config as TOML settings)."""
from __future__ import annotations

import argparse
import importlib
import io
import subprocess
import sys
from contextlib import redirect_stdout

import pytest

from viena import cli
from viena.common.service import build_parser as service_parser
from viena.settings_cli import services

CONNECTION_FLAGS = ("--connect", "--car", "--config", "--identity", "--keys", "--log-level", "--version")
CLIENT_TOOLS = ("sub", "record", "replay", "monitor", "list", "hz")


def subcommands(command: str | None = None) -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser(command)
    [action] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def version_of(parser: argparse.ArgumentParser) -> str:
    out = io.StringIO()
    with redirect_stdout(out), pytest.raises(SystemExit) as done:
        parser.parse_args(["--version"])
    assert done.value.code == 0
    return out.getvalue()


def test_every_command_answers_version():
    commands = subcommands()
    for name in ("up", "down", "status", "logs", "restart", "stop", "start", "doctor", "service",
                 "list", "hz", "info", "sub", "monitor", "record", "replay", "keys", "router"):
        assert name in commands, name
    for name, parser in {"viena": cli.build_parser(), **commands}.items():
        said = version_of(parser)
        assert "0." in said and "eclipse-zenoh" in said and "Python" in said, (name, said)


def test_every_service_and_client_tool_takes_the_connection_flags():
    parsers = {f"viena-{name}": service_parser(cls) for name, cls in services().items()}
    commands = subcommands()
    parsers.update({f"viena {name}": commands[name] for name in CLIENT_TOOLS})
    for name, parser in parsers.items():
        for flag in CONNECTION_FLAGS:
            assert flag in parser._option_string_actions, (name, flag)
        assert "0." in version_of(parser)
    for name in ("record", "replay", "monitor", "list", "hz", "sub"):
        assert "--timeout" in commands[name]._option_string_actions, name


def test_unit_only_where_a_service_has_units():
    with_units = {name for name, cls in services().items()
                  if "--unit" in service_parser(cls)._option_string_actions}
    assert with_units == {"gnss", "imu"}


def test_serial_devices_take_baudrate():
    for name in ("gnss", "imu"):
        assert "--baudrate" in service_parser(services()[name])._option_string_actions


def test_router_config_is_toml_settings_and_the_zenoh_file_has_its_own_flag(tmp_path, capsys):
    from viena import router

    json5 = tmp_path / "router.json5"
    json5.write_text("{}")
    args = router.build_parser().parse_args(["--config", str(json5)])
    assert router.run(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--zenoh-config" in err[0]
    toml = tmp_path / "viena.toml"
    toml.write_text('[zenoh]\nlisten = "tcp/127.0.0.1:7999"\nconfig = "router.json5"\n')
    path, listen, connect = router.router_settings(router.build_parser().parse_args(["--config", str(toml)]))
    assert path == json5 and listen == ["tcp/127.0.0.1:7999"] and connect is None


def test_viena_steer_takes_the_connection_flags_too():
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "viena.services.steering.client", "--help"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    for flag in (*CONNECTION_FLAGS, "--timeout"):
        assert flag in run.stdout, flag
    assert "--unit" not in run.stdout


def test_a_command_loads_its_own_tool_only():
    """`viena status` on the Pi should not wait for numpy, the estimator and Foxglove to
    load: only the command's own tool module is imported (the others are listed)."""
    probe = ("import sys; from viena import cli\n"
             "try:\n    cli.main(['status', '--version'])\nexcept SystemExit:\n    pass\n"
             "print(sorted(m for m in sys.modules if m.startswith(('viena.services.estimator', "
             "'viena.foxglove', 'viena.monitor', 'numpy'))))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert loaded.returncode == 0, loaded.stderr
    assert "0." in loaded.stdout and loaded.stdout.strip().endswith("[]"), loaded.stdout
    for name, command in (("hz", "viena.hz"), ("monitor", "viena.monitor")):
        commands = subcommands(name)
        assert commands[name].description == importlib.import_module(command).__doc__
        assert commands["up"].get_default("func") is not None
