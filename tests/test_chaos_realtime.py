"""The router killed under the real car (issue 15): the one kill of the chaos test that the
lockstep runner cannot make (its bus has no router; tests/test_chaos.py kills every other
program in virtual time). The whole `sim` profile under supervisord, a steering client
armed and streaming a triangle wave, `viena record` running; the router is killed with
SIGKILL and supervisord starts it again. Asserted, with tests/test_chaos.py's helpers:

- the wheel does not follow commands that are not valid setpoints for longer than
  watchdog + 100 ms (no setpoint reaches the steering: its watchdog stops the wheel);
- the router is back (a new pid, RUNNING) and every key that flowed before flows again
  within 5 s of the kill (every zenoh client reconnects by itself);
- the estimator (its inputs cut while the router was gone) is back under 2 m within 30 s;
- the recorder lost no sample that a second subscriber saw outside the router's absence;
  what was missed meanwhile is in its file as a sequence gap, reported.
"""
from __future__ import annotations

import os
import signal
import time

import pytest
from test_chaos import (
    BACK_WITHIN_S,
    ESTIMATOR_BACK_WITHIN_S,
    ESTIMATOR_ERROR_M,
    GNSS_CEP_M,
    Client,
    Kill,
    Watcher,
    recorder_losses,
    recording_gaps,
    tracking_share,
    wheel_after,
)
from vienatest import VIENA, Processes, open_session, sim_profile_up, supervisor, wait_for_line, wait_until

from viena.common.recording import Recording
from viena.services.steering.client import SteeringClient

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=40)]


def test_the_router_killed(tmp_path, capsys):
    procs = Processes()
    run = tmp_path / "run"
    with sim_profile_up(run, VIENA_SIM_GNSS_CEP_M=str(GNSS_CEP_M)) as (env, router):
        sup = supervisor(run)
        with open_session(router) as watch_session, open_session(router) as client_session:
            watcher = Watcher(watch_session)
            try:
                _router_killed(env, router, sup, watcher, client_session, procs, tmp_path, capsys)
            finally:
                procs.stop_all()
                watcher.close()


def _router_killed(env, router, sup, watcher, client_session, procs, tmp_path, capsys) -> None:
    # the car settled: steering calibrated and the estimator on the truth
    probe = SteeringClient(client_session, timeout_s=1.0)
    assert wait_until(lambda: probe.ask("calibration", {}).get("calibration", {}).get("state") == "done",
                      90, period=0.5), "the steering never calibrated"
    assert wait_until(lambda: watcher.error_under(ESTIMATOR_ERROR_M, 0.0) is not None, 90, period=0.5), \
        "the estimator never came within 2 m of the truth"
    out = tmp_path / "router.mcap"
    recorder = procs.start(*VIENA, "record", "--connect", router, "-o", out, "-q", env=env)
    wait_for_line(recorder.stderr, "recording viena/**")
    client = Client(client_session)
    assert wait_until(lambda: len(client.accepted_times()) >= 40, 30), "the client never steered"
    t_record_from = time.monotonic()
    keys = {k for k in watcher.keys_heard_since(time.monotonic() - 2.0)
            if "/health" in k or k.endswith(("truth", "fix", "sample", "state"))}
    time.sleep(2.0)
    steering_share = tracking_share(client, watcher, time.monotonic() - 3.0, time.monotonic())
    assert wait_until(client.steered_lately, 10, period=0.05), "the client does not steer before the kill"

    pid = sup.getProcessInfo("router")["pid"]
    os.kill(pid, signal.SIGKILL)
    kill, t_wall_ns = Kill("router", time.monotonic()), time.time_ns()

    def back() -> bool:
        info = sup.getProcessInfo("router")
        return info["statename"] == "RUNNING" and info["pid"] not in (0, pid)
    end = kill.t + 15.0
    back_s = None
    if wait_until(back, end - time.monotonic(), period=0.05):
        t_back = time.monotonic()
        back_s = t_back - kill.t
        if wait_until(lambda: keys <= watcher.keys_heard_since(t_back), end - time.monotonic(), period=0.05):
            kill.flowing_s = time.monotonic() - kill.t
            kill.last_key = max(keys, key=lambda k: watcher.first_heard_after(k, t_back)).split("/", 2)[2]
    since = kill.t + (back_s or 0.0)
    if wait_until(lambda: watcher.error_under(ESTIMATOR_ERROR_M, since) is not None,
                  ESTIMATOR_BACK_WITHIN_S + 5, period=0.2):
        kill.estimator_s = watcher.error_under(ESTIMATOR_ERROR_M, since) - kill.t
    else:
        kill.estimator_note = watcher.estimator_summary(kill.t)
    wait_until(client.steered_lately, 60, period=0.05)     # closes the window of the wheel check
    client.stop()
    t_record_to = time.monotonic() - 1.0
    recorder.send_signal(signal.SIGINT)
    _, err = recorder.communicate(timeout=30)
    assert recorder.returncode == 0, err
    wheel_after(kill, time.monotonic(), client, watcher)

    outage = (kill.t, kill.t + (kill.flowing_s or BACK_WITHIN_S))
    recording = Recording(out)
    lost, lost_in_outage = recorder_losses(recording, watcher, t_record_from + 1.0, t_record_to, outage)
    wall_outage = (t_wall_ns, t_wall_ns + int(1e9 * (outage[1] - outage[0])))
    gaps = [g for g in recording_gaps(recording)
            if g[2] < wall_outage[1] + 1_000_000_000 and g[3] > wall_outage[0] - 1_000_000_000]
    with capsys.disabled():
        span = max((g[3] - g[2] for g in gaps), default=0) / 1e9
        print(f"\nrouter killed: watchdog {client.watchdog_s:.2f} s; the wheel tracked the command in "
              f"{steering_share:.0%} of the truth samples while the client steered undisturbed; back "
              f"{_s(back_s)}, every key flowing {_s(kill.flowing_s)} ({kill.last_key} last), estimator "
              f"< {ESTIMATOR_ERROR_M} m {_s(kill.estimator_s)}, client out {kill.client_out_s:.2f} s, wheel "
              f"followed invalid {kill.tracked_invalid_s:.2f} s")
        print(f"  recorder: {recording.count} samples, {recording.report() or 'complete'}; lost of what a "
              f"second subscriber saw: {len(lost)} (+{len(lost_in_outage)} as the router came back); gap while "
              f"the router was gone: {sum(g[1] for g in gaps)} samples on {len({g[0] for g in gaps})} keys, "
              f"up to {span:.2f} s")

    assert steering_share > 0.8                   # else the wheel check below sees nothing
    assert back_s is not None and kill.flowing_s is not None and kill.flowing_s <= BACK_WITHIN_S, kill
    assert kill.tracked_invalid_s <= client.watchdog_s + 0.1, kill
    assert kill.estimator_s is not None and kill.estimator_s <= ESTIMATOR_BACK_WITHIN_S, \
        f"the estimator not back under {ESTIMATOR_ERROR_M} m: {kill.estimator_note} ({kill})"
    assert lost == [], lost[:10]
    assert recording.complete and not recording.problems


def _s(value: float | None) -> str:
    return "never" if value is None else f"{value:.2f} s"
