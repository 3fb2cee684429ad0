"""When `viena up` secures a profile and when it refuses to start one: the checks run
before supervisord is started, so a refused profile starts nothing."""
from __future__ import annotations

import subprocess
import sys

import pytest

from viena import compose
from viena.profile_security import SecurityRefusal, router_listen, secure_environment

VIENA = [sys.executable, "-m", "viena.cli"]


def env_of(profile: str) -> dict[str, str]:
    return compose.environment(profile)


@pytest.fixture(autouse=True)
def private_run(tmp_path, monkeypatch):
    monkeypatch.setenv("VIENA_RUN", str(tmp_path / "run"))
    monkeypatch.delenv("VIENA_LINK", raising=False)
    monkeypatch.delenv("VIENA_KEYS", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))     # no real keys here


def test_profiles_default_to_tls_on_the_car_and_tcp_on_one_machine():
    assert compose.link_default("pi") == "tls"
    assert compose.link_default("laptop") == "tls"
    assert compose.link_default("sim") == "tcp"


def test_the_pi_router_listens_on_every_interface():
    env = env_of("pi")
    assert router_listen(compose.profile_file("pi"), {**env, "VIENA_LINK": "tcp"}).startswith("tcp/0.0.0.0:")
    assert router_listen(compose.profile_file("sim"), {**env_of("sim"), "VIENA_LINK": "tls"}).startswith("tls/127.0.0.1:")


def test_pi_without_keys_is_refused_with_how_to_make_them():
    with pytest.raises(SecurityRefusal, match=r"no keys for car 'elettra'.*viena keys init.*--insecure"):
        secure_environment(compose.profile_file("pi"), env_of("pi"), False, False, None)


def test_pi_on_plain_tcp_needs_insecure(monkeypatch):
    monkeypatch.setenv("VIENA_LINK", "tcp")
    with pytest.raises(SecurityRefusal, match=r"would listen on tcp/0\.0\.0\.0:\d+ without TLS"):
        secure_environment(compose.profile_file("pi"), env_of("pi"), False, False, None)
    out = secure_environment(compose.profile_file("pi"), env_of("pi"), False, True, None)
    assert out["VIENA_LINK"] == "tcp" and out["VIENA_INSECURE"] == "1"


def test_sim_stays_open_on_loopback_and_secure_on_request(tmp_path):
    out = secure_environment(compose.profile_file("sim"), env_of("sim"), False, False, None)
    assert out == {"VIENA_LINK": "tcp", "VIENA_CAR": "elettra"}
    with pytest.raises(SecurityRefusal, match="no keys"):
        secure_environment(compose.profile_file("sim"), env_of("sim"), True, False, None)


def test_secure_names_every_missing_identity(store):
    (store.dir / "razor0.pem").rename(store.dir / "razor0.pem.away")
    try:
        with pytest.raises(SecurityRefusal, match=r"no identity 'razor0'"):
            secure_environment(compose.profile_file("sim"), env_of("sim"), True, False, str(store.dir))
    finally:
        (store.dir / "razor0.pem.away").rename(store.dir / "razor0.pem")
    out = secure_environment(compose.profile_file("sim"), env_of("sim"), True, False, str(store.dir))
    assert out["VIENA_LINK"] == "tls" and out["VIENA_KEYS"] == str(store.dir.resolve())


def test_viena_up_refuses_in_one_line_and_starts_nothing(tmp_path):
    up = subprocess.run([*VIENA, "up", "--profile", "pi", "-d", "--free-ports"], capture_output=True,
                        text=True, timeout=60)
    assert up.returncode == 1
    assert up.stderr.startswith("viena: profile pi: no keys for car 'elettra'") and up.stderr.count("\n") == 1
    assert not (tmp_path / "run" / "supervisord.pid").exists()


def test_the_pi_store_made_as_the_docs_say_starts_the_pi_profile(store, tmp_path):
    """docs/deployment.md: `viena keys export router gnss0 gnss1 razor0 steering estimator
    autopilot -o DIR` on the trusted machine is all the Pi needs; no ca.key, no person's key."""
    from viena.keys_cli import main as keys

    pi = tmp_path / "pi-keys"
    assert keys(["--keys", str(store.dir), "export", "router", "gnss0", "gnss1", "razor0", "steering",
                 "estimator", "autopilot", "recorder", "-o", str(pi)]) == 0
    assert not (pi / "ca.key").exists() and not (pi / "pilot.key").exists() and (pi / "pilot.pem").exists()
    out = secure_environment(compose.profile_file("pi"), env_of("pi"), False, False, str(pi))
    assert out["VIENA_LINK"] == "tls" and out["VIENA_KEYS"] == str(pi.resolve())
