"""`viena-pilot` as a process on zenoh, steering the EPOS twin through `viena-steering`,
with an estimator stand-in publishing the car's state on a straight road: routes and
their refusals, start and stop, the stops for estop, a silent or invalid estimator, and
the pilot killed while following (the steering's watchdog stops the wheel; restarted, the
pilot is idle). The sim car with the real estimator in the loop is the closed-loop test's."""
from __future__ import annotations

import json
import queue
import signal
import subprocess
import threading
import time

import msgpack
import pytest
from vienatest import (
    PYTHON,
    collect,
    fast_sweeping_twin,
    open_session,
    steering_on,
    wait_for_line,
    wait_for_queryable,
    wait_until,
)

from viena.common.geodesy import LocalFrame
from viena.common.payload import is_json_text
from viena.common.samples.pilot import PATH
from viena.common.samples.pilot import STATE as PILOT_STATE
from viena.common.samples.steering import STATE as STEERING_STATE
from viena.services.pilot.model.route import checked
from viena.services.pilot.model.sim_loop import loop_route
from viena.services.sim.model.truth import IST_ORIGIN

pytestmark = [pytest.mark.slow,  # processes: a pilot and a steering, with watchdogs, a route flood among
              pytest.mark.car(seconds=45)]    # them: in the car lane, not beside another car

CAR = "viena/elettra"
FRAME = LocalFrame(*IST_ORIGIN)


def north_road_geojson(length_m: float = 400.0, every_m: float = 10.0) -> bytes:
    n = int(length_m / every_m) + 1
    pts = [FRAME.geodetic_of_enu_exact(0.0, i * every_m, IST_ORIGIN[2])[:2] for i in range(n)]
    return json.dumps(checked(pts, [None] * n, "points").to_geojson()).encode()


def megabyte_of_points() -> bytes:
    """A point list of 1 MB (10^6 bytes: the router passes messages up to 1 MiB)."""
    points = json.dumps([{"lat": 38.7369 + i * 1e-5, "lon": -9.1395} for i in range(30_000)]).encode()
    return points[:999_998].rsplit(b"},", 1)[0] + b"}]"


class FakeEstimator:
    """Publishes estimator states at 50 Hz: the car driving north along x = `x_m` at 4 m/s,
    with any field overridden; `silent` stops it."""

    def __init__(self, session):
        import time
        self._time = time
        self.pub = session.declare_publisher(f"{CAR}/estimator/state")
        self.x_m, self.y_m, self.overrides, self.silent = 0.3, 1.0, {}, False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            if self.silent:
                continue
            self.y_m += 4.0 * 0.02
            lat, lon, _ = FRAME.geodetic_of_enu(self.x_m, self.y_m, 0.0)
            state = {"t": self._time.time_ns(), "mode": "navigating", "position_valid": True,
                     "heading_valid": True, "origin": list(IST_ORIGIN), "enu_m": [self.x_m, self.y_m, 0.0],
                     "yaw_rad": 0.0, "speed_mps": 4.0, "sigma_h_m": 0.05, "lat_deg": lat, "lon_deg": lon}
            state.update(self.overrides)
            self.pub.put(msgpack.packb(state))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.pub.undeclare()


class Latest:
    """The newest sample of a key, decoded."""

    def __init__(self, session, key: str, schema):
        self.value: dict = {}
        self._q: queue.Queue = queue.Queue()
        self.sub = session.declare_subscriber(key, lambda s: self._q.put(s.payload.to_bytes()))
        self.schema = schema

    def until(self, condition, timeout: float = 5.0) -> bool:
        def check():
            while not self._q.empty():
                self.value = self.schema.decode(self._q.get())
            return bool(self.value) and condition(self.value)
        return wait_until(check, timeout)


@pytest.fixture
def car(procs, router, session, tmp_path):
    """The steering service on its twin, ready; an estimator stand-in; state watchers."""
    twin = fast_sweeping_twin()
    config = tmp_path / "car.toml"
    _, ready = steering_on(procs, router, twin, config)
    steering = Latest(session, f"{CAR}/steering/state", STEERING_STATE)
    pilot = Latest(session, f"{CAR}/pilot/state", PILOT_STATE)
    estimator = FakeEstimator(session)
    assert steering.until(ready, 30.0), steering.value
    yield {"steering": steering, "pilot": pilot, "estimator": estimator, "config": config}
    estimator.close()
    steering.sub.undeclare()
    pilot.sub.undeclare()
    twin.stop()


def start_pilot(procs, router, config, session, *flags):
    # The 200 ms staleness stop is checked on a simulated clock (test_pilot_core.py); here the
    # stand-in estimator is a thread in this process, and a loaded 2-core machine has held
    # its samples back 210 ms: the bound is looser, and a silent estimator still trips it.
    proc = procs.python("-m", "viena.services.pilot.service", "--connect", router, "--config", config,
                        "--log-level", "INFO", "--max-estimate-age-s", "1.0", *flags)
    wait_for_line(proc.stderr, "pilot ready", 20.0)
    assert wait_for_queryable(session, f"{CAR}/pilot/cmd")
    return proc


#: the router lets a command query through per client and key at most every 50 ms
#: (compose/zenoh/router.json5, "command-queries"); one sooner is dropped, never answered
QUERY_GAP_S = 0.06
_asked: dict[str, float] = {}


def ask(session, name: str, payload: bytes | None) -> dict:
    wait_s = _asked.get(name, -QUERY_GAP_S) + QUERY_GAP_S - time.monotonic()
    if wait_s > 0:
        time.sleep(wait_s)
    _asked[name] = time.monotonic()
    replies = [r.ok for r in session.get(f"{CAR}/pilot/{name}", payload=payload, timeout=5.0) if r.ok]
    assert len(replies) == 1
    data = replies[0].payload.to_bytes()
    return json.loads(data) if is_json_text(data) else msgpack.unpackb(data)


def following(session, car) -> None:
    assert car["pilot"].until(lambda st: st["estimate_age_s"] is not None and st["estimate_age_s"] < 0.1)
    answer = ask(session, "route", north_road_geojson())
    assert answer["status"] == "accepted" and answer["route"]["properties"]["points"] == 41
    # A start the pilot stopped again before its drive was under way (a setpoint unanswered
    # within 0.25 s on a starved machine: not what these tests check) is started again, once
    for _ in range(2):
        assert ask(session, "cmd", b'{"cmd": "start"}') == {"status": "accepted", "mode": "following"}
        if car["pilot"].until(lambda st: st["mode"] == "stopped" or (st["armed"] and st["setpoints"] > 5), 10.0) \
                and car["pilot"].value["mode"] == "following":
            break
    assert car["steering"].until(lambda st: st["armed"] and st["owner"] is not None, 10.0), \
        (car["steering"].value, car["pilot"].value)
    assert car["pilot"].until(lambda st: st["mode"] == "following" and st["armed"] and st["setpoints"] > 5)
    # 0.3 m east of a northbound road: right of it, so it steers left
    assert car["pilot"].until(lambda st: st["wheel_cmd_deg"] > 0 and abs(st["cross_track_m"] + 0.3) < 0.01)


def test_routes_start_stop_and_estop(procs, router, session, car):
    start_pilot(procs, router, car["config"], session)
    assert car["pilot"].until(lambda st: st["mode"] == "idle" and st["route_points"] == 0)
    assert ask(session, "route", None) == {"status": "rejected", "reason": "no route yet"}
    assert ask(session, "cmd", b"start")["reason"] == "no route: send one on pilot/route"

    # bad routes: one clear rejection each, nothing steered
    far = [(lat + 0.09, lon) for lat, lon in loop_route(10).points]            # 10 km north
    bad = {
        b"": "no route yet",
        b"[]": "the route has no points",
        json.dumps([{"lat": 38.7369, "lon": -9.1395}]).encode(): "1 point",
        b'[{"lat": NaN, "lon": -9.1}, {"lat": 38.7, "lon": -9.1}]': "latitude is not finite",
        json.dumps({"type": "LineString", "coordinates": [[lo, la] for la, lo in far]}).encode(): "km from the car",
        megabyte_of_points(): "bytes: at most",
        json.dumps({"type": "LineString", "coordinates": "here"}).encode(): "without a list of coordinates",
    }
    for payload, reason in bad.items():
        answer = ask(session, "route", payload or None)
        assert answer["status"] == "rejected" and reason in answer["reason"], (reason, answer)
    assert car["pilot"].until(lambda st: st["route_points"] == 0 and st["setpoints"] == 0)
    assert not car["steering"].value["armed"]

    following(session, car)
    assert ask(session, "route", None)["route"]["properties"]["points"] == 41
    [path] = collect(session, f"{CAR}/pilot/path", 1, timeout=10.0, decode=PATH.decode)
    assert len(path["lat_deg"]) == 41 and path["form"] == "geojson" and path["length_m"] == pytest.approx(400.0, abs=0.05)
    assert "send stop first" in ask(session, "route", north_road_geojson(100.0))["reason"]

    assert ask(session, "cmd", json.dumps({"cmd": "stop"}).encode()) == {"status": "accepted", "mode": "stopped"}
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and st["reason"] == "stop command"
                              and not st["armed"])
    assert car["steering"].until(lambda st: not st["armed"] and st["watchdog"] == "ok"), car["steering"].value

    following(session, car)
    session.put(f"{CAR}/steering/estop", b"{}")
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and st["reason"] == "estop" and not st["armed"])
    assert car["steering"].until(lambda st: not st["armed"])
    assert ask(session, "cmd", msgpack.packb({"cmd": "bogus"}))["status"] == "rejected"


def test_a_silent_or_invalid_estimator_stops_steering(procs, router, session, car):
    start_pilot(procs, router, car["config"], session)
    following(session, car)
    car["estimator"].silent = True
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and not st["armed"])
    assert car["pilot"].value["reason"].startswith("estimate stale")
    assert car["steering"].until(lambda st: not st["armed"] and st["watchdog"] == "ok")

    car["estimator"].silent = False
    following(session, car)
    car["estimator"].overrides = {"mode": "aligning"}
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and not st["armed"])
    assert car["pilot"].value["reason"] == "estimate not valid: estimator aligning"

    car["estimator"].overrides = {"sigma_h_m": 3.0}
    # refused for the older state until the pilot has read the new one; never started
    expected = "estimate too uncertain: sigma 3.00 m (at most 2.50 m)"
    assert wait_until(lambda: ask(session, "cmd", b"start")["reason"] == expected, 5.0)
    assert car["pilot"].value["mode"] == "stopped"


def test_killing_the_pilot_leaves_the_wheel_to_the_watchdog_and_a_restart_is_idle(procs, router, session, car):
    proc = start_pilot(procs, router, car["config"], session)
    following(session, car)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=5)
    assert car["steering"].until(lambda st: not st["armed"] and st["watchdog"] == "tripped", 5.0), \
        car["steering"].value
    start_pilot(procs, router, car["config"], session)
    assert car["pilot"].until(lambda st: st["mode"] == "idle" and not st["armed"] and st["route_points"] == 0)


def test_sigterm_while_following_gives_the_lease_back(procs, router, session, car):
    proc = start_pilot(procs, router, car["config"], session)
    following(session, car)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=5) == 0
    assert car["steering"].until(lambda st: not st["armed"]), car["steering"].value
    assert car["steering"].value["watchdog"] == "ok"            # disarmed by the pilot, not tripped


def cli(router: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "viena.pilot_cli", *args, "--connect", router, "--timeout", "10"],
                          capture_output=True, text=True, timeout=60)


def test_the_command_line(procs, router, session, car, tmp_path):
    start_pilot(procs, router, car["config"], session)
    route = tmp_path / "road.geojson"
    route.write_bytes(north_road_geojson())
    sent = cli(router, "route", "send", route)
    assert sent.returncode == 0 and "route accepted: 41 checkpoints, 400 m (geojson); pilot idle" in sent.stdout, sent
    shown = tmp_path / "shown.geojson"
    assert cli(router, "route", "show", "-o", shown).returncode == 0
    assert json.loads(shown.read_text())["geometry"]["coordinates"] == \
        json.loads(route.read_text())["geometry"]["coordinates"]

    bad = tmp_path / "bad.csv"
    bad.write_text("38.7369,-9.1395\n")
    refused = cli(router, "route", "send", bad)
    assert refused.returncode == 1 and refused.stderr.strip() == \
        "viena route: route refused: the route has 1 point: at least 2 are needed"
    assert cli(router, "route", "send", tmp_path / "missing.csv").returncode == 2

    assert car["pilot"].until(lambda st: st["estimate_age_s"] is not None and st["estimate_age_s"] < 0.1)
    started = cli(router, "pilot", "start")
    assert started.returncode == 0 and started.stdout.strip() == "pilot following", started
    status = cli(router, "pilot", "status", "--json")
    assert json.loads(status.stdout)["mode"] == "following"
    assert "following" in cli(router, "pilot", "status").stdout
    assert cli(router, "pilot", "stop").stdout.strip() == "pilot stopped"
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and not st["armed"])

    recorded = tmp_path / "recorded.geojson"
    rec = cli(router, "route", "record", "-o", recorded, "--every-m", "2", "--seconds", "3")
    assert rec.returncode == 0, rec.stderr
    coords = json.loads(recorded.read_text())["geometry"]["coordinates"]
    assert len(coords) >= 3                         # 4 m/s for 3 s, a point every 2 m
    assert cli(router, "route", "send", recorded).returncode == 0


@pytest.mark.parametrize("setpoints_as, reason", [("put", "steering stopped: "),
                                                  ("query", "steering refused a setpoint: ")])
def test_an_estop_the_pilot_does_not_hear_stops_it_through_the_steering(procs, router, session, car,
                                                                        setpoints_as, reason):
    """An estop by query (no put for the pilot to hear): with puts the steering's state
    shows it disarmed; with queries the next setpoint is refused. Either way: stopped."""
    start_pilot(procs, router, car["config"], session, "--setpoints-as", setpoints_as)
    following(session, car)
    replies = list(session.get(f"{CAR}/steering/estop", payload=b"{}", timeout=5.0))
    assert replies and replies[0].ok is not None
    assert car["pilot"].until(lambda st: st["mode"] == "stopped" and not st["armed"])
    assert car["pilot"].value["reason"].startswith(reason), car["pilot"].value["reason"]


def test_malformed_and_flooding_routes_are_answered_and_never_stop_a_drive(procs, router, session, car):
    """Issue 24: a route nested 200,000 deep stopped the autopilot ("internal error", a
    traceback each), and floods of 220 KB routes left route queries unanswered. Now: every
    one answered with its reason, a line at most every 10 s, the drive going on."""
    proc = start_pilot(procs, router, car["config"], session)
    following(session, car)
    nested = b"[" * 200_000
    assert "send stop first" in ask(session, "route", nested)["reason"]       # not even read while following
    assert "bytes: at most" in ask(session, "route", megabyte_of_points())["reason"]
    for _ in range(50):
        session.put(f"{CAR}/pilot/route", nested)
    steered = car["pilot"].value["setpoints"]
    assert car["pilot"].until(lambda st: st["setpoints"] > steered + 40 or st["mode"] != "following", 10.0)
    state = car["pilot"].value
    # what this checks is that no route stops the drive: a machine starved enough to stop it
    # for a reason of its own (a setpoint unanswered in 0.25 s: CI once) says another reason
    assert state["mode"] == "following" or not state["reason"].startswith("internal error"), state
    assert state["mode"] != "following" or car["steering"].value["armed"]

    assert ask(session, "cmd", b"stop")["mode"] == "stopped"
    assert "nested deeper than 8 levels" in ask(session, "route", nested)["reason"]
    big = north_road_geojson(4800.0, 1.0)                                       # 4,801 points, ~200 KB
    done = threading.Event()

    def flood(other) -> None:                          # another client, as the flooder was
        while not done.is_set():               # at the router's 200/s: faster would only be cut
            other.put(f"{CAR}/pilot/route", big)   # there, and take the car lane's CPU here
            done.wait(0.005)
    with open_session(router) as other:
        flooder = threading.Thread(target=flood, args=(other,), daemon=True)
        flooder.start()
        try:
            answers = [ask(session, "route", north_road_geojson()) for _ in range(20)]   # each answered
        finally:
            done.set()
            flooder.join()
    assert {a["status"] for a in answers} <= {"accepted", "rejected"}
    assert all(a["status"] == "accepted" or a["reason"].startswith("busy") for a in answers), answers
    # the flood's last routes may be read after the last answer above: this one comes after them
    assert wait_until(lambda: ask(session, "route", north_road_geojson())["status"] == "accepted", 20.0)
    assert car["pilot"].until(lambda st: st["mode"] == "idle" and st["route_points"] == 41), car["pilot"].value

    proc.send_signal(signal.SIGTERM)
    _, log = proc.communicate(timeout=10)
    assert "Traceback" not in log and "step failed" not in log
    assert log.count("refused: route (") <= 2, log            # throttled: each cause once per 10 s
