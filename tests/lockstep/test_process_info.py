"""Every process says who it is on <service>[/<unit>]/info (common/samples/info.py): at
start, again a second later, then every 10 s, with its host, versions and the settings it
runs with after its file and flags; on the virtual clock, so the count is exact."""
from __future__ import annotations

from viena.common.samples.info import INFO, monitor_view, settings_map
from viena.common.samples.topics import INFO as INFO_TOPIC
from viena.common.samples.topics import topic_of_key
from viena.lockstep_car import LockstepCar

PROGRAMS = ["sim", "gnss0", "razor0", "estimator"]


def test_every_process_publishes_its_info_with_its_settings():
    with LockstepCar(seed=1, programs=PROGRAMS) as car:
        infos = car.collect("viena/elettra/**/info", INFO.decode)
        car.run_for(21.5)
    by_process: dict[tuple, list[dict]] = {}
    for sample in infos:
        by_process.setdefault((sample["service"], sample["unit"]), []).append(sample)
    assert set(by_process) == {("sim", None), ("gnss", "gnss0"), ("imu", "razor0"), ("estimator", None)}
    for samples in by_process.values():
        times_s = [(s["t"] - samples[0]["t"]) / 1e9 for s in samples]
        assert [s["seq"] for s in samples] == list(range(len(samples))) and len(samples) == 4
        assert [round(t) for t in times_s] == [0, 1, 11, 21]          # at start, then every 10 s
        assert len({s["started"] for s in samples}) == 1 and samples[0]["versions"]["eclipse-zenoh"]
    gnss = by_process[("gnss", "gnss0")][0]["settings"]
    assert gnss["port"] == "mem://gnss0" and gnss["protocol"] == "novatel"     # as the lockstep car sets them
    assert monitor_view(by_process[("sim", None)][0])["settings"] == str(len(by_process[("sim", None)][0]["settings"]))


def test_the_info_topic_is_latched_and_found_by_key():
    topic, chunks = topic_of_key("viena/elettra/imu/razor0/info")
    assert topic is INFO_TOPIC and INFO_TOPIC.latched and chunks == {"service": "imu", "unit": "razor0"}
    assert topic_of_key("viena/elettra/estimator/info")[0] is INFO_TOPIC


def test_settings_become_plain_values():
    from dataclasses import dataclass, field
    from pathlib import Path

    @dataclass
    class Inner:
        gain: float = 2.0

    @dataclass
    class Settings:
        port: str = "socket://127.0.0.1:5001"
        where: Path = Path("/tmp/x")
        arm: tuple = (1.0, 2.0)
        inner: Inner = field(default_factory=Inner)

    assert settings_map(Settings()) == {"port": "socket://127.0.0.1:5001", "where": "/tmp/x", "arm": [1.0, 2.0],
                                        "inner": {"gain": 2.0}}
    assert settings_map(object()) == {} and settings_map(Settings) == {}
