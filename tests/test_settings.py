"""Settings declared once (common/settings.py): each service's dataclass gives its defaults,
reads its TOML tables and flags with one-line errors, and makes its README's table."""
from __future__ import annotations

import argparse
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

from viena.common.config import expand_env, load_toml
from viena.common.errors import ConfigError
from viena.common.service import build_parser
from viena.common.settings import from_mapping, load, markdown, part, setting, specs, toml_table
from viena.services.estimator import Estimator, EstimatorSettings
from viena.services.estimator.service import EstimatorService
from viena.services.gnss.service import GnssService
from viena.services.sim.service import SimService
from viena.services.steering.service import SteeringService
from viena.settings_cli import main as settings_main
from viena.settings_cli import services, stale_readmes

COMPOSE = Path(__file__).resolve().parents[1] / "compose"
SERVICES = services()


def read(cls, toml: dict, *flags: str, unit: str | None = None):
    """What the service would run with, given a TOML file's contents and its flags."""
    args = build_parser(cls).parse_args([*flags, "--config", "f.toml"])
    return cls.read_settings(toml, unit or getattr(args, "unit", None) or cls.default_unit, args)


def test_every_service_is_found():
    assert set(SERVICES) == {"estimator", "gnss", "imu", "ntrip", "pilot", "recorder", "sim", "steering"}


def test_the_service_readmes_show_the_settings_as_declared():
    """`viena settings --write` makes them; edit the dataclass, then run it."""
    assert stale_readmes(list(SERVICES.values())) == []
    assert settings_main(["--check"]) == 0


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_each_setting_has_one_line_of_help_and_a_default_it_accepts(name):
    for s in specs(SERVICES[name].settings_class).values():
        assert s.help and "\n" not in s.help, s.name
        assert s.check(s.default, "default") == s.default, s.name


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_the_toml_template_reads_back_as_the_defaults(name):
    """`viena settings --toml`, uncommented, is a valid table holding exactly the defaults."""
    cls = SERVICES[name].settings_class
    text = "\n".join(line.removeprefix("# ") for line in toml_table(cls, name).splitlines())
    assert from_mapping(cls, tomllib.loads(text)[name], "template") == cls()


def test_a_unit_table_overrides_the_service_table_and_a_flag_both():
    toml = {"gnss": {"baudrate": 9600, "period_s": 0.1,
                     "gnss0": {"port": "/dev/ttyUSB0"},
                     "gnss1": {"port": "socket://127.0.0.1:5002", "baudrate": 38400}}}
    gnss0 = read(GnssService, toml, "--unit", "gnss0")
    assert (gnss0.port, gnss0.baudrate, gnss0.period_s) == ("/dev/ttyUSB0", 9600, 0.1)
    gnss1 = read(GnssService, toml, "--unit", "gnss1")
    assert (gnss1.port, gnss1.baudrate) == ("socket://127.0.0.1:5002", 38400)
    flagged = read(GnssService, toml, "--unit", "gnss1", "--baud", "4800", "--logs", "BESTPOS", "BESTVEL")
    assert (flagged.port, flagged.baudrate, flagged.logs) == ("socket://127.0.0.1:5002", 4800,
                                                             ("BESTPOS", "BESTVEL"))


@pytest.mark.parametrize("cls, toml, message", [
    (GnssService, {"gnss": {"baudrat": 1}},
     "f.toml [gnss]: unknown setting 'baudrat' (known: baudrate, command_timeout_s, corrections, corrections_baudrate,"),
    (GnssService, {"gnss": {"gnss0": {"period_s": "fast"}}},
     "f.toml [gnss.gnss0]: setting 'period_s' must be float, got 'fast'"),
    (GnssService, {"gnss": {"logs": ["BESTXYZ", "GPGGA"]}},
     "f.toml [gnss]: setting 'logs' must hold only \"BESTXYZ\", \"BESTPOS\", \"BESTVEL\""),
    (GnssService, {"gnss": {"dynamics": "CAR"}},
     "f.toml [gnss]: setting 'dynamics' must be one of \"AIR\""),
    (SteeringService, {"steering": {"margin_deg": "wide"}},
     "f.toml [steering]: setting 'margin_deg' must be float, got 'wide'"),
    (SteeringService, {"steering": {"node_id": 1.5}},
     "f.toml [steering]: setting 'node_id' must be int, got 1.5"),
    (EstimatorService, {"estimator": {"use_magnetometer": 1}},
     "f.toml [estimator]: setting 'use_magnetometer' must be bool, got 1"),
    (EstimatorService, {"estimator": {"gnss_lever_arm_m": {"gnss0": [0.5, "up", 1.5]}}},
     "f.toml [estimator]: setting 'gnss_lever_arm_m' must be table of list of float"),
    (SimService, {"sim": 3}, "f.toml: [sim] must be a table"),
])
def test_a_bad_setting_is_one_line_naming_file_table_and_setting(cls, toml, message):
    with pytest.raises(ConfigError) as err:
        read(cls, toml)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_environment_text_becomes_the_setting_type(monkeypatch):
    """${VAR} is expanded before the settings are read, so numbers and booleans come as text."""
    monkeypatch.setenv("Q_SIZE", "50")
    monkeypatch.setenv("USE_MAG", "false")
    toml = expand_env({"estimator": {"queue_size": "${Q_SIZE}", "use_magnetometer": "${USE_MAG}",
                                     "madgwick_beta": "${BETA:-0.02}"}})
    s = read(EstimatorService, toml)
    assert (s.queue_size, s.estimator.use_magnetometer, s.estimator.madgwick_beta) == (50, False, 0.02)


def test_flags_of_every_kind():
    s = read(EstimatorService, {}, "--origin", "38.7", "-9.1", "100", "--no-use-magnetometer",
             "--gnss-lever-arm-m", '{"gnss0": [0, 1, 2]}', "--imu-key", "imu/razor0/sample")
    assert s.estimator.origin == (38.7, -9.1, 100.0)
    assert s.estimator.use_magnetometer is False
    assert s.estimator.gnss_lever_arm_m == {"gnss0": (0.0, 1.0, 2.0)}
    assert s.imu_key == "imu/razor0/sample"
    sim = read(SimService, {"sim": {"devices": ["gnss0"], "parked_s": 2}}, "--device", "gnss1",
               "--device", "razor0")
    assert sim.devices == ("gnss1", "razor0") and sim.car.parked_s == 2.0
    steering = read(SteeringService, {}, "--interface", "slcan", "--node-id", "3", "--sweep-settle-s", "0.2")
    assert (steering.drive.interface, steering.drive.node_id) == ("slcan", 3)
    assert steering.calibration.sweep_settle_s == 0.2


def test_a_bad_flag_stops_the_parser():
    with pytest.raises(SystemExit):
        build_parser(GnssService).parse_args(["--protocol", "ubx"])
    with pytest.raises(SystemExit):
        build_parser(EstimatorService).parse_args(["--gnss-lever-arm-m", "{not json"])


@pytest.mark.parametrize("profile", sorted(p.stem for p in COMPOSE.glob("*.toml")))
def test_every_compose_profile_holds_only_known_settings(profile):
    toml = load_toml(COMPOSE / f"{profile}.toml")
    for cls in SERVICES.values():
        table = toml.get(cls.name, {})
        units = {k for k, v in table.items() if isinstance(v, dict) and k not in specs(cls.settings_class)}
        for unit in (units if cls.default_unit else set()) | {cls.default_unit}:
            read(cls, toml, unit=unit)


def test_the_estimator_takes_its_dataclass_or_a_dict_of_some_names():
    assert Estimator(EstimatorSettings(use_magnetometer=False)).settings.use_magnetometer is False
    assert Estimator({"gnss_max_rate_hz": 5, "origin": [38.7, -9.1, 100]}).settings == EstimatorSettings(
        gnss_max_rate_hz=5.0, origin=(38.7, -9.1, 100.0))
    with pytest.raises(ConfigError, match="estimator settings: unknown setting 'gnss_rate_hz'"):
        Estimator({"gnss_rate_hz": 5})


# -- the mechanism itself ------------------------------------------------------------------------
@dataclass(frozen=True)
class Inner:
    limit_deg: float = setting(29.0, "the lock | either side")


@dataclass(frozen=True)
class Outer:
    name: str = setting("a", "a name", choices=("a", "b"))
    inner: Inner = part(Inner, "the inner part")


def test_parts_are_named_flat_and_built_nested():
    assert list(specs(Outer)) == ["name", "limit_deg"]
    assert load(Outer, [({"limit_deg": 10}, "one"), ({"name": "b"}, "two")]) == Outer("b", Inner(10.0))
    with pytest.raises(ConfigError, match="two: setting 'name' must be one of \"a\", \"b\", got 'c'"):
        load(Outer, [({"limit_deg": 10}, "one"), ({"name": "c"}, "two")])


def test_the_markdown_table_escapes_what_would_break_it():
    text = markdown(Outer)
    assert "| `name` | str | `\"a\"` | a name; one of `\"a\"`, `\"b\"` |" in text
    assert "**inner**: the inner part" in text
    assert "| `limit_deg` | float | `29.0` | the lock \\| either side |" in text


def test_a_setting_declared_twice_or_not_at_all_is_refused():
    @dataclass(frozen=True)
    class Twice:
        limit_deg: float = setting(1.0, "again")
        inner: Inner = part(Inner, "the inner part")

    @dataclass(frozen=True)
    class Bare:
        limit_deg: float = 1.0

    with pytest.raises(TypeError, match="two settings named 'limit_deg'"):
        specs(Twice)
    with pytest.raises(TypeError, match="declare it with setting"):
        specs(Bare)


def test_viena_settings_prints_a_table_and_refuses_an_unknown_service(capsys):
    assert settings_main(["imu"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("## [imu]") and "| `port` | str | `\"\"` |" in out
    assert settings_main(["imu", "--toml"]) == 0
    assert capsys.readouterr().out.startswith("[imu]\n# port = \"\"")
    assert settings_main(["gps"]) == 2
    have = sorted(services())                      # every service (estimator, gnss, imu, sim, steering, ...)
    assert {"estimator", "gnss", "imu", "pilot", "sim", "steering"} <= set(have)
    assert f"no service 'gps' (have {', '.join(have)})" in capsys.readouterr().err


def test_a_service_without_settings_reads_none():
    from viena.common.service import Service

    class Bare(Service):
        name = "bare"

    args = argparse.Namespace(config=None)
    assert Bare.read_settings({}, None, args) == Bare.settings_class()
