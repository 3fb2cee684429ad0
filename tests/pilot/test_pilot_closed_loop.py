"""Closed loop on the simulated car: the estimator in the loop, never the truth. The sim
profile runs (twins, device services, steering, estimator); viena-pilot follows the
40 m x 24 m loop from where the car is, while the simulated person drives the speed.

The truth's cross-track error is the pilot's tracking error plus the estimator's own
position error, which the pilot cannot see (docs/pilot.md#accuracy). Round the loop, the
sim's receivers are of RTK grade (CEP 5 cm), so what is measured against the truth is the
pilot's tracking: the issue's 0.3 m RMS and 1.0 m max. The GNSS cut runs on the car's own
single-point receivers (CEP 1.8 m): the estimate is about 1 m off there, and the bound is
1 m beyond the estimate's own error."""
from __future__ import annotations

import threading

import pytest
from vienatest import open_session, sim_profile_up, wait_for_line, wait_for_queryable

from benchmarks.faults import supervisor
from benchmarks.pilot import LiveLoop, rms

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=60, realtime=True)]  # the whole sim profile, minutes

#: the sim's receivers (compose/sim.toml [sim.gnss*] cep_m): RTK grade, and the car's own
RTK_GRADE, SINGLE_POINT = {"VIENA_SIM_GNSS_CEP_M": "0.05"}, {}


@pytest.fixture(params=[pytest.param(RTK_GRADE, id="rtk")])
def sim_profile(request, tmp_path_factory):
    """One profile per test (not per module): two never run at once on a 2-core machine."""
    with sim_profile_up(tmp_path_factory.mktemp("run"), **request.param) as up:
        env, _ = up
        # the profile's own pilot (idle) makes way for the one each test starts with its settings
        supervisor(env).stopProcess("pilot")
        yield up


@pytest.fixture
def live(sim_profile, procs):
    env, router = sim_profile
    # The 200 ms staleness stop is checked on a simulated clock (test_pilot_core.py) and
    # with a silent estimator (test_pilot_service.py); here a loaded 2-core machine running
    # the whole car can hold a sample back longer than that, so the bound is looser.
    pilot = procs.python("-m", "viena.services.pilot.service", "--connect", router,
                         "--max-estimate-age-s", "1.0", "--log-level", "INFO", env=env)
    wait_for_line(pilot.stderr, "pilot ready", 30.0)
    with open_session(router) as session:
        assert wait_for_queryable(session, "viena/elettra/pilot/cmd")
        loop = LiveLoop(session)
        yield loop, env
        loop.close()


#: the steering's stops for its drive's silence (services/steering/model/core.py)
DRIVE_TRIPS = ("no feedback from the drive", "drive heartbeat lost")


def unless_the_steering_trips(drive_once):
    """A drive; once more if the steering's own watchdog stopped the first (on a loaded
    2-core machine its drive feedback can miss its 200 ms deadline: a stop the pilot must
    not override by arming again itself, and not the pilot's failure)."""
    drive = drive_once()
    if drive.mode == "stopped" and any(trip in drive.reason for trip in DRIVE_TRIPS):
        drive = drive_once()
    return drive


def test_the_pilot_drives_the_sim_car_round_the_loop(live):
    loop, _ = live
    drive = unless_the_steering_trips(loop.drive)
    assert (drive.mode, drive.reason) == ("finished", "route end"), drive.figures()
    assert drive.checkpoint_miss_m.max() <= 2.0, drive.figures()
    assert rms(drive.estimate_error_m) <= 0.2, drive.figures()        # the receivers are RTK grade
    assert rms(drive.cross_track_m) <= 0.3, drive.figures()
    assert abs(drive.cross_track_m).max() <= 1.0, drive.figures()


def drive_with_a_gnss_cut(loop: LiveLoop, env: dict, cuts: list[dict]):
    """A drive round the loop with both receivers stopped for 5 s, 5 s into it; what the
    cut did goes to `cuts`."""
    cut: dict = {}
    cuts.append(cut)

    def gnss_off_for_5_s() -> None:
        # through supervisord's XML-RPC, not `viena stop`: starting two more Python
        # processes on a busy 2-core machine could starve the pilot itself
        programs = supervisor(env)
        for unit in ("gnss0", "gnss1"):
            programs.stopProcess(unit)
        cut["off"] = True
        threading.Event().wait(5.0)
        for unit in ("gnss0", "gnss1"):
            programs.startProcess(unit)
        cut["on"] = True

    def during(t_s: float) -> None:
        if t_s > 5.0 and "thread" not in cut:
            cut["thread"] = threading.Thread(target=gnss_off_for_5_s, daemon=True)
            cut["thread"].start()

    drive = loop.drive(during=during)
    if "thread" in cut:
        cut["thread"].join(timeout=60)
    return drive


@pytest.mark.parametrize("sim_profile", [SINGLE_POINT], ids=["single-point"], indirect=True)
def test_a_gnss_cut_is_followed_on_dead_reckoning_or_stopped_for_its_sigma(live):
    loop, env = live
    cuts: list[dict] = []
    drive = unless_the_steering_trips(lambda: drive_with_a_gnss_cut(loop, env, cuts))
    assert cuts[-1].get("off") and cuts[-1].get("on"), (drive.mode, drive.reason, drive.seconds)
    if drive.mode == "stopped":
        # sigma grew past the setting, or the estimator reset itself when the fixes came
        # back far from its dead reckoning: either way the pilot stopped and said why
        assert drive.reason.startswith(("estimate too uncertain: sigma", "estimate not valid")), drive.reason
    else:
        assert (drive.mode, drive.reason) == ("finished", "route end")
        assert abs(drive.cross_track_m).max() <= 1.0 + drive.estimate_error_m.max(), drive.figures()
