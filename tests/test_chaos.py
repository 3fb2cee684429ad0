"""Chaos on the simulated car (issue 15): with a pilot armed and streaming setpoints and a
recorder running, every program of the `sim` profile is killed with SIGKILL in turn (the
router included), in an order and at moments drawn from a fixed seed; supervisord
restarts each. Asserted, per kill:

- the wheel does not move for commands that are not valid setpoints: from the car's truth
  (the twin's wheel angle), while the pilot has no accepted setpoint the wheel never
  follows the commands it keeps sending for longer than watchdog + 100 ms. (The wheel may
  move then: once the drive lets go, the person at the wheel steers it, or sweeps it for a
  new calibration; what a motor acting without a valid setpoint would show is the wheel
  following the pilot's commands. The pilot steers a triangle wave, which a wheel that
  stands or moves otherwise matches for 0.3 s at most; the check first makes sure the
  wheel does follow it while the setpoints are accepted.)
- the program is back (a new pid, RUNNING) and every key that flowed before flows again
  within 5 s of the kill;
- the estimator's horizontal error (against the truth) is back under 2 m within 30 s. The
  receivers are made better than the car's own here (GNSS_CEP_M, 0.5 m against 1.8 m):
  since the GNSS twin's errors became the real receiver's (jumps at satellite changes,
  multipath, heavy tails), an estimator restarted mid-drive starts from, and keeps, the
  receivers' error of the moment, 1.3-1.9 m with the car's receivers, so 2 m judged the
  sky. With these it judges whether the estimator comes back;
- the recorder (`viena record`, not supervised) lost no sample that a second subscriber
  saw, and the samples missing while the router was gone are reported as the gap.

The figures are printed; docs/faults.md has those of the last runs.
"""
from __future__ import annotations

import bisect
import math
import os
import random
import signal
import threading
import time
from dataclasses import dataclass, field

import msgpack
import numpy as np
import pytest
from vienatest import VIENA, Processes, open_session, sim_profile_up, supervisor, wait_for_line, wait_until

from viena.recording import Recording
from viena.services.steering.client import ConflictingReplies, SteeringClient

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=55, realtime=True)]

SEED = 15
PROGRAMS = ["router", "sim", "gnss0", "gnss1", "razor0", "steering", "estimator"]
CAR = "viena/elettra"
BACK_WITHIN_S = 5.0
ESTIMATOR_BACK_WITHIN_S = 30.0
ESTIMATOR_ERROR_M = 2.0
#: the sim's receivers' circular error probable (the car's own: 1.8 m); see the docstring
GNSS_CEP_M = 0.5
#: the pilot's command: a triangle wave, at a steady 6.4 deg/s well inside the slew limit,
#: so that a wheel standing still matches it for at most ~0.3 s (at a turn), never 0.6 s
AMPLITUDE_DEG, PERIOD_S, PILOT_RATE_HZ = 4.0, 5.0, 20.0
VALID = ("accepted", "clamped")
#: a kill that disturbs the pilot makes a setpoint fail within this
DISTURBED_WITHIN_S = 5.0
#: the wheel "tracks" the command while within this of it, DRIVE_LAG_S late (the drive's
#: position loop behind the service's 10 ms target ramp, as measured on this sim)
TRACKING_DEG, DRIVE_LAG_S = 0.5, 0.15
#: ... and only a command that has moved on this far shows the wheel following it
MOVED_ON_DEG = 1.5


def command_deg(t_s: float) -> float:
    phase = (t_s / PERIOD_S) % 1.0
    return AMPLITUDE_DEG * (4 * phase - 1 if phase < 0.5 else 3 - 4 * phase)


class Watcher:
    """A subscriber on every key of the car: when each key was last heard, every (key, seq),
    the truth (wheel and position) and the estimator's states, by arrival time."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.last_heard: dict[str, float] = {}
        self.seen: list[tuple[float, str, int]] = []          # (arrival, key, seq)
        self.truth_t: list[int] = []                           # truth `t`, ns, in order
        self.truth: list[tuple[float, float, np.ndarray]] = []  # (arrival, wheel deg, enu)
        self.errors_m: list[tuple[float, float]] = []          # (arrival, estimator horizontal error)
        self.last_state: dict = {}                             # the estimator's newest state
        self._sub = session.declare_subscriber(f"{CAR}/**", self._on_sample)

    def _on_sample(self, sample) -> None:
        now, key = time.monotonic(), str(sample.key_expr)
        try:
            value = msgpack.unpackb(sample.payload.to_bytes())
        except Exception:
            value = None
        with self.lock:
            self.last_heard[key] = now
            if not isinstance(value, dict) or not isinstance(value.get("seq"), int):
                return
            self.seen.append((now, key, value["seq"]))
            if key.endswith("/sim/truth"):
                if self.truth_t and value["t"] < self.truth_t[-1]:      # the sim restarted
                    self.truth_t.clear()
                self.truth_t.append(value["t"])
                self.truth.append((now, math.degrees(value["wheel_angle_rad"]), np.array(value["enu_m"])))
            elif key.endswith("/estimator/state"):
                self.last_state = value
                if value["position_valid"]:
                    self._estimator_error(now, value)

    def _estimator_error(self, now: float, state: dict) -> None:
        i = bisect.bisect_left(self.truth_t, state["t"])
        if 0 < i < len(self.truth_t):
            truth_enu = self.truth[len(self.truth) - len(self.truth_t) + i][2]
            self.errors_m.append((now, float(np.linalg.norm(np.array(state["enu_m"][:2]) - truth_enu[:2]))))

    def close(self) -> None:
        self._sub.undeclare()

    def estimator_summary(self, since: float) -> str:
        """Why the estimator is not back, for the failure's message: its errors since, and
        what its newest state says (no position yet, receivers on probation, a reset)."""
        with self.lock:
            errors = sorted(e for t, e in self.errors_m if t > since)
            s = self.last_state
        median = f"{errors[len(errors) // 2]:.2f} m" if errors else "none"
        return (f"{len(errors)} errors since the kill, median {median}; newest state: mode {s.get('mode')}, "
                f"position_valid {s.get('position_valid')}, admission {s.get('gnss_admission')}, "
                f"rejected {s.get('gnss_rejected')}, last reset {s.get('last_reset')}")

    def first_heard_after(self, key: str, t: float) -> float:
        with self.lock:
            return next((heard for heard, k, _ in self.seen if k == key and heard > t), math.inf)

    def keys_heard_since(self, t: float) -> set[str]:
        with self.lock:
            return {key for key, heard in self.last_heard.items() if heard > t}

    def error_under(self, limit_m: float, since: float, for_s: float = 1.0) -> float | None:
        """When the estimator's error went under `limit_m` after `since` and stayed there,
        state after state, for `for_s` (None if it has not yet)."""
        with self.lock:
            errors = [(t, e) for t, e in self.errors_m if t > since]
        start, previous = None, since
        for t, e in errors:
            if e >= limit_m or t - previous > 0.5:      # over, or silent: not back yet
                start = None
            if e < limit_m and start is None:
                start = t
            previous = t
            if start is not None and t - start >= for_s:
                return start
        return None


@dataclass
class Pilot:
    """Arms and streams the triangle wave at 20 Hz from its own session; arms again whenever its
    lease is lost (a trip, a restarted service). Keeps every reply as (time, command, status)."""

    session: object
    t0: float = field(default_factory=time.monotonic)
    replies: list = field(default_factory=list)
    watchdog_s: float = 0.5

    def __post_init__(self):
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pilot", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def accepted_times(self) -> list[float]:
        return [t for t, _, status in self.replies if status in VALID]

    def _run(self) -> None:
        client = None
        while not self._stop.is_set():
            try:
                if client is None or client.lease is None:
                    client = SteeringClient(self.session, timeout_s=1.0)
                    reply = client.arm()
                    if reply.get("status") == "accepted":
                        self.watchdog_s = reply["watchdog_s"]
                    else:
                        self._stop.wait(0.2)
                    continue
                command = command_deg(time.monotonic() - self.t0)
                try:
                    status = client.setpoint(command).get("status")
                except ConflictingReplies:          # a restarted service: arm with it afresh
                    status = "conflicting replies"
                self.replies.append((time.monotonic(), command, status))
                if status not in VALID:
                    client.lease = None
            except Exception:                       # the router is gone: try again
                client = None
                self._stop.wait(0.2)
            self._stop.wait(1.0 / PILOT_RATE_HZ)


@dataclass
class Kill:
    program: str
    pid: int
    t_mono: float
    t_wall_ns: int
    back_s: float | None = None          # new pid RUNNING
    flowing_s: float | None = None       # every key heard again
    estimator_s: float | None = None     # error back under 2 m
    last_key: str = ""                   # the key that flowed again last
    pilot_out_s: float = 0.0             # last accepted setpoint before -> next after
    tracked_invalid_s: float = 0.0       # the longest the wheel followed commands not accepted
    estimator_note: str = ""             # when the estimator did not come back: what it was doing


def kill_and_watch(sup, program: str, watcher: Watcher, keys: set[str]) -> Kill:
    pid = sup.getProcessInfo(program)["pid"]
    os.kill(pid, signal.SIGKILL)
    kill = Kill(program, pid, time.monotonic(), time.time_ns())
    end = kill.t_mono + 15.0

    def back() -> bool:
        info = sup.getProcessInfo(program)
        return info["statename"] == "RUNNING" and info["pid"] not in (0, pid)
    if wait_until(back, end - time.monotonic(), period=0.05):
        kill.back_s = time.monotonic() - kill.t_mono
        t_back = time.monotonic()
        if wait_until(lambda: keys <= watcher.keys_heard_since(t_back), end - time.monotonic(), period=0.05):
            kill.flowing_s = time.monotonic() - kill.t_mono
            kill.last_key = max(keys, key=lambda k: watcher.first_heard_after(k, t_back)).split("/", 2)[2]
    return kill


def estimator_back(watcher: Watcher, t_kill: float, back_s: float) -> float | None:
    """Seconds from the kill until the estimator is back within ESTIMATOR_ERROR_M of the
    truth, counting only states after the killed program is back (waiting a little past
    the goal, to report how far past it is)."""
    since = t_kill + back_s
    if wait_until(lambda: watcher.error_under(ESTIMATOR_ERROR_M, since) is not None,
                  ESTIMATOR_BACK_WITHIN_S + 5, period=0.2):
        return watcher.error_under(ESTIMATOR_ERROR_M, since) - t_kill
    return None


def wheel_after(kill: Kill, until: float, pilot: Pilot, watcher: Watcher) -> None:
    """From the truth: while the pilot had no valid setpoint (from its last accepted one
    before its first failed one after the kill, to its next accepted one), the longest the wheel followed the commands it kept
    sending, once they had moved on from the last accepted one. The drive follows a
    command about DRIVE_LAG_S late; a free wheel steered by the person at it crosses the
    command now and then, for a few samples."""
    failed = [t for t, _, status in pilot.replies
              if status not in VALID and kill.t_mono <= t <= min(until, kill.t_mono + DISTURBED_WITHIN_S)]
    if not failed:
        return                                  # the pilot kept its valid setpoints
    accepted = pilot.accepted_times()
    i = bisect.bisect_left(accepted, failed[0])
    if i == 0:
        return
    t_last = accepted[i - 1]
    t_next = accepted[i] if i < len(accepted) else time.monotonic()
    kill.pilot_out_s = t_next - t_last
    last_command = next(c for t, c, s in pilot.replies if t == t_last)
    with watcher.lock:
        truth = [(t, wheel) for t, wheel, _ in watcher.truth if t_last < t < t_next]
    run_start, longest = None, 0.0
    for t, wheel in truth:
        command = command_deg(t - DRIVE_LAG_S - pilot.t0)
        if abs(wheel - command) < TRACKING_DEG and abs(command - last_command) > MOVED_ON_DEG:
            run_start = t if run_start is None else run_start
            longest = max(longest, t - run_start)
        else:
            run_start = None
    kill.tracked_invalid_s = longest


def tracking_share(pilot: Pilot, watcher: Watcher, t_from: float, t_to: float) -> float:
    """The share of truth samples in which the wheel tracks the command: near 1 while the
    pilot steers (so the check above sees a wheel that follows commands)."""
    with watcher.lock:
        truth = [(t, wheel) for t, wheel, _ in watcher.truth if t_from < t < t_to]
    tracking = [abs(wheel - command_deg(t - DRIVE_LAG_S - pilot.t0)) < TRACKING_DEG for t, wheel in truth]
    return sum(tracking) / max(len(tracking), 1)


def recording_gaps(recording: Recording) -> list[tuple[str, int, int, int]]:
    """Sequence gaps in a recording: (key, samples missing, log time before, after), within
    one run of each key's publisher (a restarted one counts from 0 again)."""
    last: dict[str, tuple[int, int]] = {}
    gaps = []
    for m in recording.messages():
        try:
            value = msgpack.unpackb(m.data)
        except Exception:
            continue
        if not isinstance(value, dict) or not isinstance(value.get("seq"), int):
            continue
        before = last.get(m.key)
        if before is not None and value["seq"] > before[0] + 1:
            gaps.append((m.key, value["seq"] - before[0] - 1, before[1], m.log_time))
        last[m.key] = (value["seq"], m.log_time)
    return gaps


def recorder_losses(recording: Recording, watcher: Watcher, t_from: float, t_to: float,
                    outage: tuple[float, float]) -> tuple[list, list]:
    """Samples a second subscriber (the watcher) saw between t_from and t_to that the
    recording lacks: (outside the router's absence, during it: the two sessions do not
    reconnect at the same moment)."""
    recorded = set()
    for m in recording.messages():
        try:
            value = msgpack.unpackb(m.data)
        except Exception:
            continue
        if isinstance(value, dict) and isinstance(value.get("seq"), int):
            recorded.add((m.key, value["seq"]))       # a restarted program reuses a seq: any match
    with watcher.lock:
        seen = [(t, key, seq) for t, key, seq in watcher.seen if t_from < t < t_to]
    lost, lost_in_outage = [], []
    for t, key, seq in seen:
        if (key, seq) not in recorded:
            (lost_in_outage if outage[0] - 1 <= t <= outage[1] + 1 else lost).append((t, key, seq))
    return lost, lost_in_outage


def test_every_program_killed_in_turn(tmp_path, capsys):
    rng = random.Random(SEED)
    order = PROGRAMS[:]
    rng.shuffle(order)
    procs = Processes()
    run = tmp_path / "run"
    with sim_profile_up(run, VIENA_SIM_GNSS_CEP_M=str(GNSS_CEP_M)) as (env, router):
        sup = supervisor(run)
        with open_session(router) as watch_session, open_session(router) as pilot_session:
            watcher = Watcher(watch_session)
            try:
                _chaos(env, router, sup, watcher, pilot_session, procs, order, rng, tmp_path, capsys)
            finally:
                procs.stop_all()
                watcher.close()


def _chaos(env, router, sup, watcher, pilot_session, procs, order, rng, tmp_path, capsys) -> None:
    # the car settled: steering calibrated and the estimator on the truth
    def steering_ready() -> bool:
        reply = SteeringClient(pilot_session, timeout_s=1.0).ask("calibration", {})
        return reply.get("calibration", {}).get("state") == "done"
    assert wait_until(steering_ready, 90, period=0.5), "the steering never calibrated"
    assert wait_until(lambda: watcher.error_under(ESTIMATOR_ERROR_M, 0.0) is not None, 90, period=0.5), \
        "the estimator never came within 2 m of the truth"
    out = tmp_path / "chaos.mcap"
    recorder = procs.start(*VIENA, "record", "--connect", router, "-o", out, "-q", env=env)
    wait_for_line(recorder.stderr, "recording viena/**")
    pilot = Pilot(pilot_session)
    pilot.start()
    assert wait_until(lambda: len(pilot.accepted_times()) >= 40, 30), "the pilot never steered"
    t_record_from = time.monotonic()
    keys = watcher.keys_heard_since(time.monotonic() - 2.0)
    keys = {k for k in keys if "/health" in k or k.endswith(("truth", "fix", "sample", "state"))}

    time.sleep(2.0)
    steering_share = tracking_share(pilot, watcher, time.monotonic() - 3.0, time.monotonic())
    kills: list[Kill] = []
    for program in order:
        time.sleep(rng.uniform(0.5, 1.5))                       # a moment drawn from the seed
        assert wait_until(lambda: pilot.accepted_times() and pilot.accepted_times()[-1] > time.monotonic() - 0.2,
                          60, period=0.05), "the pilot does not steer before the kill"
        kill = kill_and_watch(sup, program, watcher, keys)
        kills.append(kill)
        kill.estimator_s = estimator_back(watcher, kill.t_mono, kill.back_s or 0.0)
        if kill.estimator_s is None:
            kill.estimator_note = watcher.estimator_summary(kill.t_mono)
        # the pilot steering again closes this kill's window for the wheel check
        wait_until(lambda: pilot.accepted_times()[-1] > time.monotonic() - 0.2, 60, period=0.05)
    pilot.stop()
    t_record_to = time.monotonic() - 1.0
    recorder.send_signal(signal.SIGINT)
    _, err = recorder.communicate(timeout=30)
    assert recorder.returncode == 0, err
    for kill, after in zip(kills, [*kills[1:], None]):
        wheel_after(kill, after.t_mono if after else math.inf, pilot, watcher)

    router_kill = next(k for k in kills if k.program == "router")
    outage = (router_kill.t_mono, router_kill.t_mono + (router_kill.flowing_s or BACK_WITHIN_S))
    recording = Recording(out)
    lost, lost_in_outage = recorder_losses(recording, watcher, t_record_from + 1.0, t_record_to, outage)

    gaps = recording_gaps(recording)
    wall_outage = (router_kill.t_wall_ns, router_kill.t_wall_ns + int(1e9 * (outage[1] - outage[0])))
    in_outage = [g for g in gaps if g[2] < wall_outage[1] + 1_000_000_000 and g[3] > wall_outage[0] - 1_000_000_000]
    with capsys.disabled():
        print(f"\nchaos (seed {SEED}, order {' '.join(order)}): watchdog {pilot.watchdog_s:.2f} s; per "
              f"kill: program back (new pid RUNNING), every key flowing, estimator < {ESTIMATOR_ERROR_M} m "
              f"(after the kill), pilot without a valid setpoint, longest the wheel followed commands "
              f"not accepted")
        print(f"  the wheel tracked the command in {steering_share:.0%} of the truth samples while "
              f"the pilot steered undisturbed")
        for k in kills:
            print(f"  {k.program:10s} back {_s(k.back_s)}  flowing {_s(k.flowing_s)} ({k.last_key} last)  estimator "
                  f"{_s(k.estimator_s)}  pilot out {k.pilot_out_s:5.2f} s  wheel followed invalid "
                  f"{k.tracked_invalid_s:.2f} s")
        span = max((g[3] - g[2] for g in in_outage), default=0) / 1e9
        print(f"  recorder: {recording.count} samples, {recording.report() or 'complete'}; lost of what "
              f"a second subscriber saw: {len(lost)} (+{len(lost_in_outage)} as the router came back); gap while the router was gone: "
              f"{sum(g[1] for g in in_outage)} samples on {len({g[0] for g in in_outage})} keys, up to "
              f"{span:.2f} s; other sequence gaps (at their publisher's restart): "
              f"{[(g[0].split('/', 2)[2], g[1]) for g in gaps if g not in in_outage]}")

    assert steering_share > 0.8                   # else the wheel check below sees nothing
    for k in kills:
        assert k.back_s is not None and k.flowing_s is not None and k.flowing_s <= BACK_WITHIN_S, k
        assert k.tracked_invalid_s <= pilot.watchdog_s + 0.1, k
        assert k.estimator_s is not None and k.estimator_s <= ESTIMATOR_BACK_WITHIN_S, \
            f"{k.program}: the estimator not back under {ESTIMATOR_ERROR_M} m: {k.estimator_note} ({k})"
    assert lost == [], lost[:10]
    assert recording.complete and not recording.problems


def _s(value: float | None) -> str:
    return "  never" if value is None else f"{value:5.2f} s"
