"""`viena sim run`: closed-loop drives of the whole car in virtual time, as fast as the CPU allows.

    viena sim run                                   the default scenario (compose/scenarios/loop.toml)
    viena sim run gnss_outage --duration 600        a shipped scenario by name, 10 minutes of driving
    viena sim run my.toml --seed 3 --record drive.mcap --report drive.json
    viena sim run rtk --seeds 1..50                 a Monte-Carlo table, one process per seed on every core
    viena sim run --realtime 1                      paced at real time

The sim profile's programs run in this process on a virtual clock (viena.lockstep_car): the
simulated person drives the speed, and starts the pilot on the route whenever it is not
following (the loop from where the car is, or the scenario's route file); the scenario's
events happen at their times. At the end a one-screen summary: the pilot's cross-track error
against the truth, the estimator's error and the share of truths inside its 95 % ellipse,
refusals, resets, steering stops and their causes, what the events did. docs/simulation.md
says what each figure means and how scenario files are written.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import multiprocessing
import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from viena import scenario as scenarios
from viena.common import clock
from viena.common.lockstep.scheduler import START_NS
from viena.common.payload import parse_payload
from viena.common.recording import RecordingWriter
from viena.common.samples import topics
from viena.common.samples.estimator import CHI2_2D_95
from viena.common.samples.estimator import STATE as ESTIMATE
from viena.common.samples.health import HEALTH
from viena.common.samples.pilot import STATE as PILOT
from viena.common.samples.steering import STATE as STEERING
from viena.common.samples.truth import TRUTH
from viena.common.schema import unpack
from viena.lockstep_car import SIM_TOML, LockstepCar
from viena.record import Recorder
from viena.scenario import Event, Scenario, ScenarioError
from viena.services.pilot.model.path import Path as RoutePath
from viena.services.pilot.model.route import MAX_POINTS, MAX_ROUTE_BYTES, checked, parse_route

#: how often the simulated person looks at the pilot and the events are checked (virtual s)
TICK_S = 0.1
#: the person tries to start a pilot that is not following again after this long (virtual s)
RETRY_S = 1.0
#: a pilot state older than this (against the truth) is a pilot that is not there
PILOT_FRESH_S = 0.25
#: the truths kept to judge the estimator's states against (10 ms steps: 10 s)
TRUTHS_KEPT = 1000
#: how many digits the report keeps (the same seed gives the same file)
DIGITS = 4


# -- counting across restarts --------------------------------------------------------------------
class Tally:
    """Totals a program reports since it started (name -> count), summed over the drive: a
    count that went down is a new process (killed and started again), whose counts add on."""

    def __init__(self) -> None:
        self.banked: dict[str, int] = {}
        self.last: dict[str, int] = {}

    def update(self, counts: Any) -> None:
        if not isinstance(counts, dict):
            return
        counts = {str(k): int(v) for k, v in counts.items() if isinstance(v, (int, float))}
        if any(counts.get(k, 0) < v for k, v in self.last.items()):
            for k, v in self.last.items():
                self.banked[k] = self.banked.get(k, 0) + v
        self.last = counts

    def totals(self) -> dict[str, int]:
        out = dict(self.banked)
        for k, v in self.last.items():
            out[k] = out.get(k, 0) + v
        return {k: v for k, v in sorted(out.items()) if v}


def _bump(counts: dict[str, int], cause: str, n: int = 1) -> None:
    counts[cause] = counts.get(cause, 0) + n


# -- what the drive did ----------------------------------------------------------------------------
class Watch:
    """An observer on the car's bus: the truth, the estimator's states, the pilot's and the
    steering's, and the steering's health, judged as they come (on the bus's threads, in
    virtual time, so the same seed gives the same figures)."""

    def __init__(self, car: Any):
        self._truth = TRUTH.reader("t", "enu_m", "vel_enu_mps", "speed_mps", "origin")
        self._estimate = ESTIMATE.reader("t", "enu_m", "enu_cov_m2", "position_valid", "counts", "last_reset",
                                         "gnss_rejected", "input_rejected")
        self._pilot = PILOT.reader("t", "mode", "reason", "estimate_age_s")
        self._steering = STEERING.reader("trip", "fault")
        self.truth: dict | None = None            # the newest: t, enu_m, speed_mps, origin
        self._truths: dict[int, tuple] = {}       # 10 ms step -> (t, x, y, vx, vy)
        self.pilot_t, self.pilot_mode, self.pilot_reason, self.estimate_age_s = 0, "idle", None, None
        self.path: Any = None                     # the route followed, in the truth's ENU
        self._near: float | None = None
        self.cross_track_m: list[float] = []
        self.following_ns = 0
        self.finished = 0
        self.pilot_stops: dict[str, int] = {}
        self.estimate_errors_m: list[float] = []
        self.inside_95 = 0
        self.resets: dict[str, int] = {}
        self._resets_seen = 0
        self.gnss_rejected, self.input_rejected, self.setpoints_refused = Tally(), Tally(), Tally()
        self.steering_stops: dict[str, int] = {}
        self.steering_faults: dict[str, int] = {}
        self._trip, self._fault = "", ""
        session = car.session("sim-run")
        keys = car.keys
        self._subs = [
            session.declare_subscriber(keys.truth, self._on_truth),
            session.declare_subscriber(keys.of(topics.ESTIMATOR_STATE), self._on_estimate),
            session.declare_subscriber(keys.of(topics.PILOT_STATE), self._on_pilot),
            session.declare_subscriber(keys.of(topics.STEERING_STATE), self._on_steering),
            session.declare_subscriber(keys.health("steering"), self._on_steering_health)]

    def follow(self, path: Any) -> None:
        """The pilot was started on `path` (the route, in the truth's ENU metres)."""
        self.path, self._near = path, None

    @property
    def following(self) -> bool:
        """The pilot says it follows, and it said so lately."""
        truth = self.truth
        return (self.pilot_mode == "following" and truth is not None
                and truth["t"] - self.pilot_t < PILOT_FRESH_S * 1e9)

    def _on_truth(self, sample) -> None:
        t, enu, vel, speed, origin = self._truth(unpack(sample.payload.to_bytes()))
        last = self.truth
        self.truth = {"t": t, "enu_m": enu, "speed_mps": speed, "origin": origin}
        self._truths[round(t / 1e7)] = (t, enu[0], enu[1], vel[0], vel[1])
        if len(self._truths) > TRUTHS_KEPT:
            del self._truths[next(iter(self._truths))]
        if self.path is not None and self.following:
            where = self.path.project(enu[0], enu[1], near_s_m=self._near)
            self._near = where.s_m
            self.cross_track_m.append(where.cross_track_m)
            self.following_ns += t - last["t"] if last is not None else 0

    def _on_estimate(self, sample) -> None:
        t, enu, cov, valid, counts, last_reset, gnss_rejected, input_rejected = self._estimate(
            unpack(sample.payload.to_bytes()))
        resets = int(counts.get("resets", 0))
        if resets < self._resets_seen:             # a new estimator: its counts start again
            self._resets_seen = 0
        if resets > self._resets_seen:
            _bump(self.resets, str(last_reset), resets - self._resets_seen)
            self._resets_seen = resets
        self.gnss_rejected.update(gnss_rejected)
        self.input_rejected.update(input_rejected)
        at = self._truths.get(round(t / 1e7))
        if not valid or at is None:
            return
        dt = (t - at[0]) / 1e9                     # the truth moved to the state's time
        dx, dy = enu[0] - (at[1] + at[3] * dt), enu[1] - (at[2] + at[4] * dt)
        self.estimate_errors_m.append(math.hypot(dx, dy))
        ee, en, nn = cov[0], cov[1], cov[3]
        det = ee * nn - en * en
        if det > 0 and (nn * dx * dx - 2 * en * dx * dy + ee * dy * dy) / det <= CHI2_2D_95:
            self.inside_95 += 1

    def _on_pilot(self, sample) -> None:
        t, mode, reason, age = self._pilot(unpack(sample.payload.to_bytes()))
        if self.pilot_mode == "following" and mode != "following":
            if mode == "finished":
                self.finished += 1
            else:
                _bump(self.pilot_stops, cause(reason or mode))
        self.pilot_t, self.pilot_mode, self.pilot_reason, self.estimate_age_s = t, mode, reason, age

    def _on_steering(self, sample) -> None:
        trip, fault = self._steering(unpack(sample.payload.to_bytes()))
        if trip and trip != self._trip:
            _bump(self.steering_stops, cause(trip))
        if fault and fault != self._fault:
            _bump(self.steering_faults, cause(fault))
        self._trip, self._fault = trip, fault

    def _on_steering_health(self, sample) -> None:
        state = HEALTH.decode(sample.payload.to_bytes()).get("state") or {}
        self.setpoints_refused.update(state.get("setpoints_refused"))

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def cause(text: str) -> str:
    """A reason as a cause to count: its numbers taken out, so 'no setpoint for 0.31 s' and
    'no setpoint for 0.27 s' are one cause."""
    return re.sub(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?![\w.])", "#", str(text)).strip()


# -- the person in the car --------------------------------------------------------------------------
class Person:
    """Starts the pilot whenever it is not following and the car moves with a fresh
    estimate: sends the route (the loop from where the car is, as many laps as the drive
    has left, or the scenario's route file) and `start`, as `viena route send` and `viena
    pilot start` do; tries again RETRY_S later if either is refused."""

    def __init__(self, car: Any, watch: Watch, route_file: Path | None, end_s: float):
        self.car, self.watch, self.end_s = car, watch, end_s
        self.session = car.session("person")
        self.route_bytes = route_file.read_bytes() if route_file is not None else None
        self._route = parse_route(self.route_bytes) if self.route_bytes is not None else None
        self.starts = 0
        self.refusals: dict[str, int] = {}
        self._next_try_s = 0.0
        car_params = car.services["sim"].settings.car
        self.min_speed_mps = min(2.5, max(1.0, 0.8 * car_params.speed_min_mps))
        self.max_speed_mps = car_params.speed_max_mps

    def step(self, now_s: float) -> None:
        w = self.watch
        if w.following or now_s < self._next_try_s:
            return
        truth = w.truth
        if truth is None or truth["speed_mps"] < self.min_speed_mps or w.estimate_age_s is None \
                or w.estimate_age_s > 0.1:
            return
        self._next_try_s = now_s + RETRY_S
        route, payload = self._route_here(truth, now_s)
        answer = self.ask("route", payload)
        if answer.get("status") != "accepted":
            _bump(self.refusals, cause(f"route: {answer.get('reason', answer.get('status'))}"))
            return
        answer = self.ask("cmd", b'{"cmd": "start"}')
        if answer.get("status") != "accepted":
            _bump(self.refusals, cause(f"start: {answer.get('reason', answer.get('status'))}"))
            return
        self.starts += 1
        w.follow(RoutePath.from_route(route, tuple(truth["origin"])))

    def _route_here(self, truth: dict, now_s: float) -> tuple[Any, bytes]:
        if self._route is not None and self.route_bytes is not None:
            return self._route, self.route_bytes
        route = laps_from(truth["enu_m"][0], truth["enu_m"][1], ahead_m=max(2.0, 0.3 * truth["speed_mps"]),
                          metres=(self.end_s - now_s) * self.max_speed_mps)
        return route, json.dumps(route.to_geojson()).encode()

    def ask(self, name: str, payload: bytes) -> dict:
        """The pilot's answer on pilot/NAME, or {"status": "no answer"}."""
        for reply in self.session.get(self.car.keys.of(topics.BY_NAME[f"pilot.{name}"]), payload=payload, timeout=5.0):
            if reply.ok is not None:
                return parse_payload(reply.ok.payload.to_bytes(), max_bytes=2 * MAX_ROUTE_BYTES)  # echoes the route
        return {"status": "no answer"}


def laps_from(x_m: float, y_m: float, ahead_m: float, metres: float) -> Any:
    """The sim's loop from where the car is (services/pilot/model/sim_loop.py), as many
    times round as `metres` take, and one more, within the pilot's MAX_POINTS."""
    from viena.services.pilot.model.sim_loop import loop_route_from

    lap = loop_route_from(x_m, y_m, ahead_m)
    n = max(1, min(math.ceil(max(metres, 0.0) / lap.length_m) + 1, (MAX_POINTS - 1) // (len(lap) - 1)))
    points = list(lap.points[:-1]) * n + [lap.points[-1]]
    return checked(points, [None] * len(points), "points")


# -- the events ----------------------------------------------------------------------------------
class Overcast:
    """A receiver twin's sky with timed outages laid over it: in each window the receiver
    sees too few satellites for a fix (INSUFFICIENT_OBS, as in the twin's own random
    outages: services/gnss/simulator/errors.py SkyModel), outside it the sky as it was."""

    def __init__(self, sky: Any):
        self.sky = sky
        self.windows: list[tuple[float, float]] = []      # virtual monotonic s

    def at(self, t_s: float) -> Any:
        state = self.sky.at(t_s)
        now = clock.monotonic()
        if not state.outage and any(a <= now < b for a, b in self.windows):
            used = min(state.sats_used, 3)
            return replace(state, sats_used=used, sats_tracked=used + state.sats_tracked - state.sats_used,
                           outage=True)
        return state

    def __getattr__(self, name: str) -> Any:
        return getattr(self.sky, name)


class Timeline:
    """The scenario's events, applied by the driver between steps of the simulation."""

    def __init__(self, car: Any, events: tuple[Event, ...]):
        self.car = car
        self.pending: list[tuple[float, int, Event]] = [(e.at_s, i, e) for i, e in enumerate(events)]
        self.done: list[dict] = []
        self._flood_session: Any = None
        self._n = len(events)

    @property
    def next_at_s(self) -> float:
        return min((at for at, _, _ in self.pending), default=math.inf)

    def apply_due(self, now_s: float) -> None:
        while self.pending and min(self.pending)[0] <= now_s + 1e-9:
            item = min(self.pending)
            self.pending.remove(item)
            event = item[2]
            try:
                result = getattr(self, f"_{event.kind}")(event, now_s)
            except LookupError as exc:
                result = f"skipped: {exc.args[0]}"
            self.done.append({"at_s": round(now_s, 3), "what": event.describe(), "result": result})

    def _later(self, at_s: float, event: Event) -> None:
        self._n += 1
        self.pending.append((at_s, self._n, event))

    # one method per event kind (scenario.KINDS): what it did, as a few words
    def _kill(self, event: Event, now_s: float) -> str:
        if event.target not in self.car.services:
            raise LookupError(f"{event.target} is not running")
        self.car.kill(event.target)
        back = event.options["restart_after_s"]
        if back >= 0:        # supervisord starts a program that died again
            self._later(now_s + back, Event(now_s + back, "start", event.target))
        return "killed"

    def _stop(self, event: Event, now_s: float) -> str:
        if event.target not in self.car.services:
            raise LookupError(f"{event.target} is not running")
        self.car.stop(event.target)
        return "stopped"

    def _start(self, event: Event, now_s: float) -> str:
        if event.target in self.car.services:
            raise LookupError(f"{event.target} runs already")
        self.car.start(event.target)
        return "started"

    def _device(self, name: str) -> Any:
        sim = self.car.services.get("sim")
        if sim is None:
            raise LookupError("the sim is not running")
        for device_name, device in zip(sim.settings.devices, sim.devices):
            if device_name == name:
                return device.twin
        raise LookupError(f"no device {name}")

    def _gnss_outage(self, event: Event, now_s: float) -> str:
        until = clock.monotonic() + event.options["for_s"]
        for name in event.target:
            solver = getattr(self._device(name), "solver", None)
            if solver is None:
                raise LookupError(f"{name} replays a recording: no sky to take away")
            if not isinstance(solver.sky, Overcast):
                solver.sky = Overcast(solver.sky)
            solver.sky.windows.append((clock.monotonic(), until))
        return f"no fix until {now_s + event.options['for_s']:g} s"

    def _imu_bias(self, event: Event, now_s: float) -> str:
        twin = self._device(event.target)
        board = getattr(twin, "board", None)
        if board is None or getattr(twin, "truth", None) is None:
            raise LookupError(f"{event.target} replays a recording: no board to step")
        twin.board = board.with_bias_step(gyro_dps=event.options["gyro_dps"],
                                          accel_g=[mg / 1000.0 for mg in event.options["accel_mg"]])
        return "stepped"

    def _steering_fault(self, event: Event, now_s: float) -> str:
        self._device(event.target).inject_error(event.options["code"])
        return "raised"

    def _flood(self, event: Event, now_s: float) -> str:
        if self._flood_session is None:
            self._flood_session = self.car.session("flood")
        o = event.options
        payload = o["payload"].encode() if o["payload"] else bytes(i % 256 for i in range(o["bytes"]))
        key, period, count = self.car.key(event.target), 1.0 / o["rate_hz"], round(o["for_s"] * o["rate_hz"])
        session = self._flood_session

        def flood() -> None:
            for _ in range(count):
                session.put(key, payload)
                clock.sleep(period)
        with self.car.clock.group("flood"):
            clock.Thread(flood, name=f"flood-{event.target}").start()
        return f"{count} puts"


# -- one drive -------------------------------------------------------------------------------------
def drive(scenario: Scenario, seed: int = 1, duration_s: float | None = None, realtime: float | None = None,
          record: Path | None = None, foxglove: bool = False, progress: Any = None) -> dict:
    """One closed-loop drive of `scenario` in virtual time; its report (a dict that is the
    same for the same scenario, seed and duration). `progress(done_s, total_s)` is called
    every virtual second."""
    duration = scenario.duration_s if duration_s is None else duration_s
    with LockstepCar(SIM_TOML, overrides=scenario.overrides, seed=seed, realtime=realtime, cpu="auto") as car:
        t0_ns = car.clock.monotonic_ns()
        watch = Watch(car)
        person = Person(car, watch, scenario.route, duration)
        timeline = Timeline(car, scenario.events)
        recorder = _recorder(car, record, foxglove, scenario, seed) if record is not None else None
        end_ns, tick_ns, ticks = t0_ns + round(duration * 1e9), round(TICK_S * 1e9), 0
        try:
            while True:
                now_ns = car.clock.monotonic_ns()
                now_s = (now_ns - t0_ns) / 1e9
                timeline.apply_due(now_s)
                person.step(now_s)
                if now_ns >= end_ns:
                    break
                next_event_ns = t0_ns + round(timeline.next_at_s * 1e9) if timeline.pending else end_ns
                car.clock.run_for_ns(max(min(now_ns + tick_ns, next_event_ns, end_ns) - now_ns, 1))
                ticks += 1
                if progress is not None and ticks % round(1.0 / TICK_S) == 0:
                    progress(now_s, duration)
        finally:
            if recorder is not None:
                recorder.stop()
            watch.close()
        errors = [f"{thread}: {type(exc).__name__}: {exc}" for thread, exc in car.clock.errors]
    return report_of(scenario, seed, duration, watch, person, timeline, errors)


def _recorder(car: Any, path: Path, foxglove: bool, scenario: Scenario, seed: int) -> Any:
    """`viena record`'s recorder on the car's bus, every key, times in virtual time."""
    metadata = {"keyexprs": car.keys.all, "car": car.keys.car, "host": "viena sim run",
                "scenario": scenario.name, "seed": str(seed),
                "started": datetime.fromtimestamp(clock.time(), UTC).isoformat(timespec="seconds")}
    if foxglove:
        from viena.foxglove_export import FoxgloveWriter
        writer: Any = FoxgloveWriter(path, metadata=metadata)
    else:
        writer = SimWriter(path, metadata=metadata)
    recorder = Recorder(car.session("recorder"), [car.keys.all], writer)
    recorder.start()
    return recorder


class SimWriter(RecordingWriter):
    """`viena record`'s writer without its fsync every half second: that durability is for
    a car that loses power; a simulation that dies is run again."""

    def flush(self) -> None:
        pass


def _figures(values: list[float]) -> dict:
    if not values:
        return {"n": 0}
    a = np.abs(np.asarray(values, float))
    return {"rms": _r(math.sqrt(float(np.mean(a * a)))), "p95": _r(float(np.percentile(a, 95))),
            "max": _r(float(a.max())), "n": len(values)}


def _r(x: float) -> float:
    return round(x, DIGITS)


def report_of(scenario: Scenario, seed: int, duration: float, watch: Watch, person: Person,
              timeline: Timeline, errors: list[str]) -> dict:
    n = len(watch.estimate_errors_m)
    return {
        "scenario": scenario.name, "description": scenario.description, "seed": seed, "duration_s": duration,
        "pilot": {"following_s": _r(watch.following_ns / 1e9), "starts": person.starts,
                  "finished": watch.finished, "stops": dict(sorted(watch.pilot_stops.items())),
                  "start_refusals": dict(sorted(person.refusals.items())),
                  "cross_track_m": _figures(watch.cross_track_m)},
        "estimator": {"error_m": _figures(watch.estimate_errors_m),
                      "inside_95": _r(watch.inside_95 / n) if n else None,
                      "resets": dict(sorted(watch.resets.items())),
                      "gnss_rejected": watch.gnss_rejected.totals(),
                      "input_rejected": watch.input_rejected.totals()},
        "steering": {"stops": dict(sorted(watch.steering_stops.items())),
                     "faults": dict(sorted(watch.steering_faults.items())),
                     "setpoints_refused": watch.setpoints_refused.totals()},
        "events": timeline.done,
        "errors": errors,
    }


# -- what is printed -------------------------------------------------------------------------------
def _counts(counts: dict) -> str:
    if not counts:
        return "none"
    return ", ".join(f"{k} ×{v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def _stats(f: dict) -> str:
    if not f.get("n"):
        return "no samples"
    return f"RMS {f['rms']:.2f} m, p95 {f['p95']:.2f} m, max {f['max']:.2f} m"


def summary(report: dict, cost: dict | None = None) -> str:
    """The report as a person reads it: one screen."""
    p, e, s = report["pilot"], report["estimator"], report["steering"]
    head = f"{report['scenario']} (seed {report['seed']}): {report['duration_s']:g} s of driving"
    if cost:
        head += (f" in {cost['wall_s']:.1f} s ({report['duration_s'] / max(cost['wall_s'], 1e-9):.1f} x real "
                 f"time, CPU {cost['cpu_s']:.1f} s)")
    inside = "-" if e["inside_95"] is None else f"{100 * e['inside_95']:.1f} %"
    lines = [
        head,
        f"pilot       following {p['following_s']:.1f} s; started {p['starts']}x, finished {p['finished']}x",
        f"            cross-track against the truth: {_stats(p['cross_track_m'])}",
        f"            stops: {_counts(p['stops'])}",
        f"            refused: {_counts(p['start_refusals'])}",
        f"estimator   horizontal error against the truth: {_stats(e['error_m'])}",
        f"            truths inside its 95 % ellipse: {inside} (95 % when its covariance is honest)",
        f"            resets: {_counts(e['resets'])}",
        f"            fixes refused: {_counts(e['gnss_rejected'])}",
        f"            inputs refused: {_counts(e['input_rejected'])}",
        f"steering    stops: {_counts(s['stops'])}",
        f"            drive faults: {_counts(s['faults'])}",
        f"            setpoints refused: {_counts(s['setpoints_refused'])}",
    ]
    for i, event in enumerate(report["events"]):
        lines.append(f"{'events' if i == 0 else '':12s}at {event['at_s']:g} s: {event['what']}: {event['result']}")
    if cost and cost.get("log_warnings"):
        lines.append(f"log         {cost['log_warnings']} warnings and errors" +
                     (f" (in {cost['log']})" if cost.get("log") else " (--log FILE keeps them)"))
    for error in report["errors"]:
        lines.append(f"ERROR       a thread died: {error}")
    return "\n".join(lines)


@dataclass(frozen=True)
class Column:
    """A column of the Monte-Carlo table: its name in the JSON, its title, how to read it off
    a report, its format, and which way is worse."""
    key: str
    title: str
    of: Callable[[dict], Any]
    fmt: str = "{:.2f}"
    higher_is_worse: bool = True


COLUMNS = (
    Column("following_s", "follow s", lambda r: r["pilot"]["following_s"], "{:.0f}", False),
    Column("cross_track_rms_m", "xt RMS", lambda r: r["pilot"]["cross_track_m"].get("rms")),
    Column("cross_track_p95_m", "xt p95", lambda r: r["pilot"]["cross_track_m"].get("p95")),
    Column("cross_track_max_m", "xt max", lambda r: r["pilot"]["cross_track_m"].get("max")),
    Column("estimate_rms_m", "est RMS", lambda r: r["estimator"]["error_m"].get("rms")),
    Column("estimate_p95_m", "est p95", lambda r: r["estimator"]["error_m"].get("p95")),
    Column("inside_95", "in 95%", lambda r: r["estimator"]["inside_95"], "{:.1%}", False),
    Column("pilot_stops", "pilot stops", lambda r: sum(r["pilot"]["stops"].values()), "{:g}"),
    Column("steering_stops", "steer stops", lambda r: sum(r["steering"]["stops"].values()), "{:g}"),
    Column("estimator_resets", "resets", lambda r: sum(r["estimator"]["resets"].values()), "{:g}"),
)


def table_rows(reports: list[dict]) -> tuple[list[list], list, list]:
    """Per seed, then the mean and the worst of each column."""
    rows = [[c.of(r) for c in COLUMNS] for r in reports]
    mean, worst = [], []
    for k, c in enumerate(COLUMNS):
        values = [row[k] for row in rows if row[k] is not None]
        mean.append(_r(sum(values) / len(values)) if values else None)
        worst.append((max(values) if c.higher_is_worse else min(values)) if values else None)
    return rows, mean, worst


def aggregate(reports: list[dict]) -> dict:
    """The JSON of a Monte-Carlo run: the mean and worst of each column, and every report."""
    _, mean, worst = table_rows(reports)
    keys = [c.key for c in COLUMNS]
    return {"scenario": reports[0]["scenario"], "seeds": [r["seed"] for r in reports],
            "mean": dict(zip(keys, mean)), "worst": dict(zip(keys, worst)), "runs": reports}


def print_table(reports: list[dict], costs: dict[int, dict], console: Any) -> None:
    rows, mean, worst = table_rows(reports)
    table = Table(title=f"{reports[0]['scenario']}: {len(reports)} seeds x {reports[0]['duration_s']:g} s; "
                        "xt: the pilot's cross-track, est: the estimator's error, both in m against the truth")
    for title in ("seed", *(c.title for c in COLUMNS), "wall s"):
        table.add_column(title, justify="right")
    for report, row in zip(reports, rows):
        table.add_row(str(report["seed"]), *map(_cell, row, COLUMNS),
                      f"{costs.get(report['seed'], {}).get('wall_s', 0):.0f}")
    table.add_section()
    table.add_row("mean", *map(_cell, mean, COLUMNS), "")
    table.add_row("worst", *map(_cell, worst, COLUMNS), "")
    console.print(table)


def _cell(value: Any, column: Column) -> str:
    return "-" if value is None else column.fmt.format(value)


# -- logs --------------------------------------------------------------------------------------
class _Counter(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.n = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.n += 1


class _VirtualTime(logging.Filter):
    """Stamps each record with the simulation's time (the thread's clock)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.sim_s = (clock.monotonic_ns() - START_NS) / 1e9 if clock.is_virtual() else float("nan")
        return True


@contextmanager
def quiet_logs(path: Path | None) -> Iterator[_Counter]:
    """The car's logs off the screen (the summary is the screen's): counted, and written to
    `path` if given, each line stamped with its virtual time."""
    root = logging.getLogger()
    counter = _Counter()
    handlers: list[logging.Handler] = [counter]
    if path is not None:
        to_file = logging.FileHandler(path, mode="w")
        to_file.addFilter(_VirtualTime())
        to_file.setFormatter(logging.Formatter("%(sim_s)10.3f %(levelname)-7s %(name)s: %(message)s"))
        handlers.append(to_file)
    level = root.level
    root.setLevel(logging.INFO if path is not None else logging.WARNING)
    for handler in handlers:
        root.addHandler(handler)
    try:
        yield counter
    finally:
        for handler in handlers:
            root.removeHandler(handler)
            handler.close()
        root.setLevel(level)


# -- the command line ----------------------------------------------------------------------------
def seed_range(text: str) -> list[int]:
    m = re.fullmatch(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", text)
    if not m or int(m.group(1)) > int(m.group(2)):
        raise argparse.ArgumentTypeError(f"expected A..B (seeds A to B, both included), got {text!r}")
    return list(range(int(m.group(1)), int(m.group(2)) + 1))


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena sim", description=__doc__,
                                               formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="sim_command", required=True, metavar="COMMAND")
    p = sub.add_parser("run", help="a closed-loop drive in virtual time", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", nargs="?", metavar="SCENARIO",
                   help=f"a scenario file, or one shipped: {', '.join(scenarios.shipped())} (default loop)")
    p.add_argument("--route", type=Path, metavar="FILE",
                   help="follow this route (GeoJSON, point list, CSV) instead of the scenario's")
    p.add_argument("--duration", type=float, metavar="S", help="virtual seconds of driving (default: the scenario's)")
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=1, metavar="N", help="the simulation's seed (default 1)")
    seeds.add_argument("--seeds", type=seed_range, metavar="A..B",
                       help="one drive per seed, one process each on every core, and a table")
    p.add_argument("--realtime", type=float, metavar="X", help="pace the drive at X times real time")
    p.add_argument("--record", type=Path, metavar="OUT.mcap",
                   help="record every key (with --seeds: OUT-seedN.mcap); `viena replay` and `viena plot` read it")
    p.add_argument("--foxglove", action="store_true",
                   help="with --record: a recording Foxglove opens (JSON) instead of viena's own (msgpack)")
    p.add_argument("--report", type=Path, metavar="OUT.json", help="write the summary as JSON")
    p.add_argument("--log", type=Path, metavar="FILE", help="write the car's log here (virtual time stamps)")
    p.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    err = Console(stderr=True)
    try:
        scenario = scenarios.load(scenarios.resolve(args.scenario))
        if args.route is not None:
            try:
                scenario = replace(scenario, route=scenarios.route_file(args.route))
            except ScenarioError as exc:
                raise ScenarioError(f"--route: {exc}") from None
        if args.duration is not None and args.duration <= 0:
            raise ScenarioError(f"--duration: must be more than 0, got {args.duration:g}")
    except ScenarioError as exc:
        print(f"viena sim run: {exc}", file=sys.stderr)
        return 2
    if args.seeds:
        return _many(args, scenario, err)
    return _one(args, scenario, err)


def _one(args: argparse.Namespace, scenario: Scenario, err: Any) -> int:
    duration = scenario.duration_s if args.duration is None else args.duration
    columns = (TextColumn(f"{scenario.name} seed {args.seed}"), BarColumn(),
               TextColumn("{task.completed:.0f}/{task.total:.0f} s  {task.fields[speed]}"), TimeRemainingColumn())
    with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task("drive", total=duration, speed="")
        start = time.monotonic()

        def progress(done_s: float, total_s: float) -> None:
            speed = done_s / max(time.monotonic() - start, 1e-9)
            bar.update(task, completed=done_s, speed=f"{speed:.1f}x real time")
        report, cost = timed_drive(scenario, args.seed, duration, args.realtime, args.record, args.foxglove,
                                   args.log, progress)
    print(summary(report, cost))
    if args.record is not None:
        print(f"recorded into {args.record} " + ("(for Foxglove)" if args.foxglove else
                                                  f"(`viena plot {args.record}`, `viena replay {args.record}`)"))
    _write_report(args.report, report)
    return 1 if report["errors"] else 0


def timed_drive(scenario: Scenario, seed: int, duration: float, realtime: float | None, record: Path | None,
                foxglove: bool, log_path: Path | None, progress: Any = None) -> tuple[dict, dict]:
    """`drive`, with what it cost (wall and CPU seconds of this process, log lines)."""
    wall, cpu = time.monotonic(), time.process_time()
    with quiet_logs(log_path) as logged:
        report = drive(scenario, seed, duration, realtime, record, foxglove, progress)
    cost = {"wall_s": time.monotonic() - wall, "cpu_s": time.process_time() - cpu, "log_warnings": logged.n,
            "log": str(log_path) if log_path else None}
    return report, cost


def _seed_job(scenario: Scenario, seed: int, duration: float, realtime: float | None, record: Path | None,
              foxglove: bool, log_path: Path | None) -> tuple[dict, dict]:
    """One seed's drive, in a worker process."""
    return timed_drive(scenario, seed, duration, realtime, record, foxglove, log_path)


def _per_seed(path: Path | None, seed: int) -> Path | None:
    return None if path is None else path.with_name(f"{path.stem}-seed{seed}{path.suffix}")


def _many(args: argparse.Namespace, scenario: Scenario, err: Any) -> int:
    duration = scenario.duration_s if args.duration is None else args.duration
    workers = min(os.cpu_count() or 1, len(args.seeds))
    reports: dict[int, dict] = {}
    costs: dict[int, dict] = {}
    wall = time.monotonic()
    columns = (TextColumn(f"{scenario.name}: {len(args.seeds)} seeds on {workers} cores"), BarColumn(),
               MofNCompleteColumn(), TimeElapsedColumn())
    # a fresh process per seed: a drive leaves state behind in its process (the steering
    # client's setpoint counter), which would change the next one's recording
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                             max_tasks_per_child=1) as pool:
        jobs = {pool.submit(_seed_job, scenario, seed, duration, args.realtime, _per_seed(args.record, seed),
                            args.foxglove, _per_seed(args.log, seed)): seed for seed in args.seeds}
        with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("seeds", total=len(jobs))
            for job in as_completed(jobs):
                seed = jobs[job]
                reports[seed], costs[seed] = job.result()
                bar.advance(task)
    ordered = [reports[seed] for seed in args.seeds]
    print_table(ordered, costs, Console(width=None if sys.stdout.isatty() else 132))
    print(f"{len(ordered)} drives of {duration:g} s in {time.monotonic() - wall:.1f} s on {workers} processes "
          f"(CPU {sum(c['cpu_s'] for c in costs.values()):.0f} s)")
    for report in ordered:
        for error in report["errors"]:
            print(f"ERROR seed {report['seed']}: a thread died: {error}")
    _write_report(args.report, aggregate(ordered))
    return 1 if any(r["errors"] for r in ordered) else 0


def _write_report(path: Path | None, report: dict) -> None:
    if path is not None:
        path.write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
