"""`viena service install --profile pi` (issue 14): a systemd unit that starts the profile at
boot, restarts it on failure and stops it cleanly (SIGTERM to `viena up` alone, which
test_cli_programs.py shows stops every program); checked by `systemd-analyze verify` where
it exists. systemctl is replaced by a script that logs what it was asked."""
from __future__ import annotations

import shlex
import shutil
import subprocess
import sys

import pytest
from vienatest import viena

from viena import boot


def unit_settings(text: str) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for line in text.splitlines():
        if "=" in line and not line.startswith("#"):
            name, value = line.split("=", 1)
            found.setdefault(name, []).append(value)
    return found


def test_the_system_unit_starts_the_profile_at_boot_and_stops_it_cleanly(monkeypatch):
    monkeypatch.setenv("SUDO_USER", "pi")
    unit = unit_settings(boot.unit_text("pi", user_unit=False, keys="/home/pi/keys"))
    assert unit["ExecStart"] == [shlex.join([sys.executable, "-m", "viena.cli", "up", "--profile", "pi"])]
    assert unit["User"] == ["pi"] and unit["SupplementaryGroups"] == ["dialout"]
    assert unit["Restart"] == ["on-failure"] and unit["KillMode"] == ["mixed"] and unit["KillSignal"] == ["SIGTERM"]
    assert unit["WantedBy"] == ["multi-user.target"] and "network-online.target" in unit["After"][0]
    assert "VIENA_KEYS=/home/pi/keys" in unit["Environment"]
    user = unit_settings(boot.unit_text("pi", user_unit=True, insecure=True))
    assert "User" not in user and user["WantedBy"] == ["default.target"]
    assert user["ExecStart"][0].endswith("up --profile pi --insecure")


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze here")
@pytest.mark.parametrize("user", [False, True])
def test_systemd_analyze_verify_accepts_the_unit(tmp_path, user):
    flags = ["--user"] if user else []
    done = viena("service", "install", "--profile", "pi", *flags, "--dir", tmp_path)
    assert done.returncode == 0, done.stderr
    path = tmp_path / "viena-pi.service"
    # verified in system mode either way: a user manager needs a login session
    verified = subprocess.run(["systemd-analyze", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert verified.returncode == 0 and verified.stdout + verified.stderr == "", verified.stderr


def test_verify_would_catch_a_broken_unit(tmp_path):
    """The check above means something: a bad setting is reported."""
    if shutil.which("systemd-analyze") is None:
        pytest.skip("no systemd-analyze here")
    bad = tmp_path / "viena-bad.service"
    bad.write_text(boot.unit_text("pi", user_unit=False).replace("KillMode=mixed", "KillMode=mixd"))
    verified = subprocess.run(["systemd-analyze", "verify", str(bad)], capture_output=True, text=True, timeout=60)
    assert "mixd" in verified.stderr


@pytest.fixture
def fake_systemctl(tmp_path, monkeypatch):
    """A `systemctl` that logs its arguments (and fails on `enable` if told to)."""
    bin_dir, log = tmp_path / "bin", tmp_path / "systemctl.log"
    bin_dir.mkdir()
    script = bin_dir / "systemctl"
    script.write_text(f'#!/bin/sh\necho "$*" >> {log}\n'
                      'if [ -n "$FAIL_ENABLE" ] && [ "$1" = enable ]; then echo "Access denied" >&2; exit 1; fi\n')
    script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}:/usr/bin:/bin")
    monkeypatch.setattr(boot, "SYSTEM_DIR", tmp_path / "system")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    return log


def service(*argv: str) -> int:
    return boot.run(boot.build_parser().parse_args(list(argv)))


def test_install_enables_and_uninstall_removes(fake_systemctl, tmp_path, capsys):
    assert service("install", "--profile", "pi", "--now") == 0
    path = tmp_path / "system" / "viena-pi.service"
    assert "up --profile pi" in path.read_text()
    assert fake_systemctl.read_text().splitlines() == ["daemon-reload", "enable viena-pi.service",
                                                       "restart viena-pi.service"]
    assert "runs `viena up --profile pi` at boot (and now)" in capsys.readouterr().out

    fake_systemctl.write_text("")
    assert service("uninstall", "--profile", "pi") == 0
    assert not path.exists()
    assert fake_systemctl.read_text().splitlines() == ["disable --now viena-pi.service", "daemon-reload"]
    assert service("uninstall", "--profile", "pi") == 0
    assert "nothing to remove" in capsys.readouterr().out


def test_a_user_unit_goes_to_the_users_systemd(fake_systemctl, tmp_path, capsys):
    assert service("install", "--profile", "sim", "--user") == 0
    assert (tmp_path / "config" / "systemd" / "user" / "viena-sim.service").exists()
    assert fake_systemctl.read_text().splitlines() == ["--user daemon-reload", "--user enable viena-sim.service"]
    assert "loginctl enable-linger" in capsys.readouterr().out


def test_failures_are_one_line(fake_systemctl, monkeypatch, capsys):
    monkeypatch.setenv("FAIL_ENABLE", "1")
    assert service("install", "--profile", "pi") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["viena service: `systemctl enable viena-pi.service` failed: Access denied"]
    assert service("install", "--profile", "nope") == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("viena service: no profile 'nope' (have: ") and "pi" in line
