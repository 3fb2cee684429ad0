"""Each schema module says how the monitor shows its samples (`monitor_view`); the monitor
lays out what it is given and reads no field of any sample itself."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from laptop_helpers import pilot_state

import viena.monitor
from viena.common.display import Alert
from viena.common.health import Health
from viena.common.samples.estimator import STATE as ESTIMATOR_STATE
from viena.common.samples.estimator import monitor_view as estimator_view
from viena.common.samples.fix import FIX
from viena.common.samples.fix import monitor_view as gnss_view
from viena.common.samples.health import HEALTH, HealthReport
from viena.common.samples.health import monitor_view as health_view
from viena.common.samples.imu import SAMPLE
from viena.common.samples.imu import monitor_view as imu_view
from viena.common.samples.pilot import STATE as PILOT_STATE
from viena.common.samples.pilot import monitor_view as pilot_view
from viena.common.samples.steering import STATE as STEERING_STATE
from viena.common.samples.steering import monitor_view as steering_view
from viena.common.samples.truth import TRUTH
from viena.common.samples.truth import monitor_view as truth_view
from viena.services.estimator import Estimator
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import truth_sample

VIEWS = [(FIX, gnss_view), (SAMPLE, imu_view), (STEERING_STATE, steering_view),
         (ESTIMATOR_STATE, estimator_view), (PILOT_STATE, pilot_view), (TRUTH, truth_view),
         (HEALTH, health_view)]


def test_the_simulated_cars_truth_and_a_fresh_estimate_read_as_numbers():
    car = SimCar()
    for _ in range(200):
        truth = car.step(0.01)
    cells = truth_view(TRUTH.decode(TRUTH.encode(truth_sample(truth))))
    assert list(cells) == ["position ENU m", "speed", "yaw", "wheel"]
    assert cells["speed"].endswith(" m/s") and cells["yaw"].endswith("°") and "-" not in cells.values()
    state = estimator_view(Estimator({"origin": [38.7369, -9.1395, 100.0]}).state())
    assert state["mode"] == "waiting" and state["heading"] == "none (not valid)"
    assert state["σ pos"].endswith(" m")
    # the estimator shows its own estimate and nothing of a route: that is the pilot's panel
    assert list(state) == ["mode", "position ENU m", "σ pos", "σ h/v", "speed", "yaw", "pitch / roll",
                           "heading", "gnss used"]


def test_the_pilot_shows_its_mode_cross_track_and_the_way_to_the_next_checkpoint():
    """Half a metre east of a route north, 12 m along: the next checkpoint (20 m north) is
    8 m away, a little to the left (bearing and turn negative, the Titans' signs)."""
    cells = pilot_view(pilot_state(x_m=0.5, y_m=12.0))
    assert list(cells) == ["mode", "checkpoint", "next", "cross-track", "wheel"]
    assert cells["mode"] == "following" and not isinstance(cells["mode"], Alert)
    assert cells["checkpoint"] == "2 of 11"
    assert cells["next"] == "8.0 m at -3.6°, turn -3.6°"
    assert cells["cross-track"] == "-0.50 m"                  # right of the route
    assert cells["wheel"] == "4.3°"                           # steering back left
    facing_nnw = pilot_view(pilot_state(x_m=0.5, y_m=12.0, yaw_deg=30.0))    # compass heading -30°
    assert facing_nnw["next"] == "8.0 m at -3.6°, turn 26.4°"     # now the checkpoint is to the right


def test_a_stopped_pilot_asks_to_be_noticed_and_no_route_reads_as_such():
    stopped = pilot_view(pilot_state(stop_reason="estimate stale (0.35 s)"))
    assert stopped["mode"] == "stopped (estimate stale (0.35 s))" and isinstance(stopped["mode"], Alert)
    assert stopped["wheel"] == "-"                            # nothing commanded any more
    idle = pilot_view({"t": 1, "seq": 0, "mode": "idle", "route_points": 0, "checkpoint": None})
    assert idle == {"mode": "idle", "checkpoint": "no route", "next": "-", "cross-track": "-", "wheel": "-"}


def test_errors_in_a_health_report_ask_to_be_noticed():
    health = Health("gnss", "gnss0")
    health.count("reconnects", 2)
    quiet = health_view(health.snapshot(), age_s=0.5)
    assert quiet["errors"] == "-" and not isinstance(quiet["errors"], Alert) and quiet["reconnects"] == "2"
    health.error("silences")
    loud = health_view(health.snapshot())
    assert loud["errors"] == "silences 1" and isinstance(loud["errors"], Alert)
    assert list(loud) == list(HealthReport().cells())            # the monitor's columns


def anything():
    scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**64, 2**64), st.text(max_size=5),
                        st.floats(allow_nan=True, allow_infinity=True))
    return st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                        | st.dictionaries(st.text(max_size=3), inner, max_size=3), max_leaves=8)


@pytest.mark.parametrize("schema, view", VIEWS, ids=[s.name for s, _ in VIEWS])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_view_shows_any_map_as_text_and_never_raises(schema, view, data):
    """Whatever came on the key: any of the schema's fields with any value, and others."""
    sample = data.draw(st.dictionaries(st.sampled_from([*schema.fields, "other"]), anything(), max_size=12))
    cells = view(sample)
    assert isinstance(cells, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in cells.items())


def test_the_monitor_reads_no_field_of_any_sample():
    """No `x["name"]` nor `x.get("name")` with a field of a schema it shows: those belong to
    the schema modules' views."""
    tree = ast.parse(Path(viena.monitor.__file__).read_text())
    fields = {name for schema, _ in VIEWS for name in schema.fields} - {"t", "seq"}
    read = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            read.add(node.slice.value)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
              and node.args and isinstance(node.args[0], ast.Constant)):
            read.add(node.args[0].value)
    assert read & fields == set()
