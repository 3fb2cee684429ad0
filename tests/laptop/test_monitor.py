"""The monitor: its data model with a test clock, its rendering of odd samples, and the
live dashboard on the simulated car."""
from __future__ import annotations

import io
import signal
import time

import pytest
from laptop_helpers import SIM_HEALTH_KEY, pilot_state, start_sim, viena, wait_for_samples
from rich.console import Console
from vienatest import wait_until

from viena.monitor import LiveFeed, MonitorModel, render

HEALTH = {"t": 1, "seq": 3, "service": "gnss", "unit": "gnss0", "uptime_s": 12.0,
          "rates_hz": {"fix": 20.0}, "counts": {"fix": 240, "reconnects": 2},
          "errors": {"crc": 0, "timeout": 3}, "last_sample_age_s": 0.04,
          "state": {"connected": True}}


def text_of(view) -> str:
    console = Console(file=io.StringIO(), width=220, color_system=None)
    console.print(render(view))
    return console.file.getvalue()


def test_a_service_is_alive_while_its_token_is_and_lost_after():
    model = MonitorModel()
    model.token("viena/elettra/alive/gnss/gnss0", True, now=10.0)
    model.sample("viena/elettra/gnss/gnss0/health", HEALTH, now=10.5, schema="viena.health/1")
    [s] = model.view(now=11.0).services
    assert (s.name, s.status) == ("gnss/gnss0", "alive")
    report = s.report                                     # common/samples/health.py reads the health
    assert report.rates_hz == {"fix": 20.0} and report.errors == {"timeout": 3.0}
    assert report.reconnects == 2 and report.last_sample_age_s == 0.04
    assert report.uptime_s == pytest.approx(12.5) and not s.health.stale

    model.token("viena/elettra/alive/gnss/gnss0", False, now=12.0)
    [s] = model.view(now=15.0).services
    assert s.status == "lost" and s.status_age_s == pytest.approx(3.0)
    assert s.health.stale and s.health.age_s == pytest.approx(4.5)
    shown = text_of(model.view(now=15.0))
    assert "lost 3.00 s" in shown and "STALE 4.50 s" in shown


def test_health_without_a_token_is_shown_as_such():
    model = MonitorModel()
    model.sample("viena/elettra/sim/health", {**HEALTH, "service": "sim", "unit": None}, now=1.0)
    model.token("viena/other-car/alive/sim", True, now=1.0)            # another car: not ours
    [s] = model.view(now=1.2).services
    assert (s.name, s.status) == ("sim", "no token")


def test_values_carry_their_age_and_turn_stale():
    model = MonitorModel(data_stale_s=1.0)
    fix = {"t": 1, "seq": 1, "valid": True, "pos_status": "SOL_COMPUTED", "pos_type": "SINGLE",
           "sats_used": 7, "sats_tracked": 9, "ecef_sigma_m": [1.0, 2.0, 2.0], "lat_deg": 38.7,
           "lon_deg": -9.1, "height_m": 100.0, "latency_s": 0.05}
    for i in range(21):                                   # 20 Hz for a second
        model.sample("viena/elettra/gnss/gnss0/fix", fix, now=100.0 + i * 0.05)
    view = model.view(now=101.2)
    aged = view.gnss["gnss0"]
    assert aged.age_s == pytest.approx(0.2) and not aged.stale
    assert aged.rate_hz == pytest.approx(20.0)
    shown = text_of(view)
    assert "SINGLE (single)" in shown and "7/9" in shown and "3.00 m" in shown
    later = model.view(now=104.0)
    assert later.gnss["gnss0"].stale and later.gnss["gnss0"].rate_hz == 0.0
    assert "STALE 3.00 s" in text_of(later)


def test_odd_and_unknown_samples_render_without_crashing():
    model = MonitorModel()
    odd = [
        ("viena/elettra/gnss/gnss0/fix", {"t": 1}),
        ("viena/elettra/gnss/gnss1/fix", {"valid": "maybe", "ecef_sigma_m": [1, "x"], "sats_used": None,
                                          "latency_s": float("nan"), "lat_deg": [1, 2]}),
        ("viena/elettra/imu/razor0/sample", {"accel_mps2": [0.1, 0.2], "gyro_radps": "fast", "mag_T": [1e-5] * 3}),
        ("viena/elettra/steering/state", {"armed": False, "owner": None, "measured_rad": 0.1,
                                          "watchdog": {"expired": True, "deadline_s": 0.2},
                                          "fault": "0x8611 following error", "new_field": [1, [2]]}),
        ("viena/elettra/estimator/state", {"mode": "coasting", "enu_var_m2": [-1.0, 4.0, 1.0],
                                           "yaw_rad": 1.0, "from_a_newer_estimator": [38.7, -9.1]}),
        ("viena/elettra/pilot/state", {"mode": "stopped", "reason": 3, "route_points": None,
                                       "checkpoint_distance_m": "far", "wheel_cmd_deg": float("inf")}),
        ("viena/elettra/sim/truth", {"euler_rad": None, "speed_mps": "3"}),
        ("viena/elettra/some/thing", 42),
        ("viena/elettra/estimator/health", {"rates_hz": "x", "errors": None, "state": 7}),
    ]
    for key, value in odd:
        model.sample(key, value, now=1.0)
    model.bad_sample("viena/elettra/broken", "not valid msgpack")
    model.token("viena/elettra/alive", True, now=1.0)               # malformed token key
    shown = text_of(model.view(now=1.5))
    for piece in ("armed", "no", "measured °", "5.73", "expired yes", "following error",
                  "coasting", "viena/elettra/some/thing", "undecodable: not valid msgpack",
                  "estimator", "pilot", "stopped (3)"):
        assert piece in shown


def test_the_pilot_has_its_panel_where_the_estimator_showed_one_target():
    model = MonitorModel(data_stale_s=1.0)
    model.sample("viena/elettra/estimator/state", {"mode": "navigating"}, now=5.0)
    for i in range(21):                                   # the pilot's 20 Hz for a second
        model.sample("viena/elettra/pilot/state", pilot_state(), now=5.0 + i * 0.05,
                     schema="viena.pilot.state/1")
    view = model.view(now=6.1)
    assert view.pilot.rate_hz == pytest.approx(20.0) and not view.pilot.stale
    assert view.pilot.key == "viena/elettra/pilot/state" and view.pilot not in view.others
    shown = text_of(view)
    pilot_panel = shown[shown.index("\npilot"):]                # below the estimator's panel
    for piece in ("following", "2 of 11", "8.0 m at -3.6°, turn -3.6°", "-0.50 m", "4.3°", "20.0"):
        assert piece in pilot_panel
    assert "8.0 m at" not in shown[:shown.index("\npilot")]
    assert "STALE" in text_of(model.view(now=8.0))


@pytest.fixture
def sim(procs, router, session, tmp_path):
    proc = start_sim(procs, router, tmp_path)
    wait_for_samples(session, SIM_HEALTH_KEY)
    return proc


def test_live_feed_sees_the_sim_and_its_loss(sim, session):
    model, feed = MonitorModel(), LiveFeed()
    subs = feed.subscribe(session, model.keys)

    def sim_status():
        feed.poll()
        feed.apply(model)
        view = model.view(time.monotonic())
        return {s.name: s.status for s in view.services}.get("sim"), view

    try:
        assert wait_until(lambda: sim_status()[0] == "alive" and sim_status()[1].truth is not None, 10)
        assert wait_until(lambda: (sim_status()[1].truth.rate_hz or 0) > 50, 5)
        # the health comes once a second, the first a second after the start: wait for it
        # rather than assume the truth's rate took longer than that
        assert wait_until(lambda: sim_status()[1].services[0].health is not None, 5)
        _, view = sim_status()
        assert not view.truth.stale
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=10)
        assert wait_until(lambda: sim_status()[0] == "lost", 10)
        time.sleep(1.2)
        _, view = sim_status()
        assert view.truth.stale
    finally:
        for sub in subs:
            sub.undeclare()


def test_monitor_command_shows_the_car(sim, router):
    result = viena("monitor", "--connect", router, "--duration", "2.5", timeout=30)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "services" in out and "sim" in out and "alive" in out
    assert "simulator truth" in out and "STALE" not in out
