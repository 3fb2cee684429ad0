"""viena.pilot.state/1: what the pilot is doing, on viena/<car>/pilot/state (20 Hz).

Angles in degrees as their names say (people read them; the Titans' geo values were
degrees too), distances in m. Signs: `cross_track_m` > 0 when the car is left of the
route; the heading errors are the way to go minus the car's compass heading, +-180 deg,
> 0: turn right (the Titans' convention, docs/pilot.md#keys-and-state); `wheel_cmd_deg` > 0 left
(the steering's convention). Fields about the route and the car are null when there is
no route or no usable estimate. Issue 28 added the precision rule's fields as optional
ones, so the name stays /1 (docs/dataflow.md#samples).
"""
from __future__ import annotations

from viena.common.display import Alert, fmt_num, fmt_unit, number
from viena.common.schema import F, Schema

MODES = ("idle", "following", "finished", "stopped")

STATE = Schema("viena.pilot.state/1", {
    "t": F.time,                                   # when this state was made, ns UTC
    "seq": F.int,
    "mode": F.enum(*MODES),
    "reason": F.optional(F.str),                   # why stopped (or why the last start was refused)
    "controller": F.str,                           # pure_pursuit or stanley
    "armed": F.bool,                               # the pilot holds a steering lease
    "route_points": F.int,                         # 0: no route
    "route_length_m": F.optional(F.float),
    "checkpoint": F.optional(F.int),               # index of the next checkpoint; null past the last
    "checkpoint_distance_m": F.optional(F.float),
    "checkpoint_bearing_deg": F.optional(F.float),        # from north, clockwise, +-180
    "checkpoint_heading_error_deg": F.optional(F.float),  # bearing - heading, > 0: turn right
    "progress_m": F.optional(F.float),             # along the route from its first checkpoint
    "progress": F.optional(F.float),               # the same as a fraction of the route, 0..1
    "cross_track_m": F.optional(F.float),
    "heading_error_deg": F.optional(F.float),      # the route's way - heading, > 0: turn right
    "wheel_cmd_deg": F.optional(F.float),          # the last wheel angle sent
    "lookahead_m": F.optional(F.float),
    "target_enu_m": F.optional(F.vec(2)),          # the point aimed at, in the estimator's ENU
    "route_speed_mps": F.optional(F.float),        # the route's advised speed here (the person drives)
    "estimate_age_s": F.optional(F.float),
    "setpoints": F.int,                            # setpoints sent since start
    # the precision rule (issue 28, model/precision.py; optional: older states lack them)
    "precision_ok": F.optional(F.bool),            # the GNSS solution is good enough to follow by
    "precision_kind": F.optional(F.str),           # the solution kind judged (the estimate's gnss_kind)
    "precision_diff_age_s": F.optional(F.float),   # ... and its corrections' age
    "precision_reason": F.optional(F.str),         # why not good enough
})


#: the route the pilot holds, on viena/<car>/pilot/path: when it is taken and every few
#: seconds after, so a recording (`viena record`) and a late viewer (`viena plot`, the
#: monitor, Foxglove's map) have it
PATH = Schema("viena.pilot.path/1", {
    "t": F.time,
    "form": F.str,                                 # geojson, points, titans, csv
    "lat_deg": F.list(F.float),                    # the checkpoints, in order
    "lon_deg": F.list(F.float),
    "speeds_mps": F.list(F.optional(F.float)),     # advised speeds, null where none
    "length_m": F.float,
})


def path_sample(route, t_ns: int) -> dict:
    """A viena.pilot.path/1 sample of a Route (model/route.py)."""
    return {"t": t_ns, "form": route.form, "lat_deg": [p[0] for p in route.points],
            "lon_deg": [p[1] for p in route.points], "speeds_mps": list(route.speeds_mps),
            "length_m": route.length_m}


def monitor_view(state: dict) -> dict[str, str]:
    """How the monitor shows a pilot state (any map): what it does, and the way to the next
    checkpoint as the Titans' geo node gave it; a stop asks to be noticed."""
    mode = str(state.get("mode", "-"))
    if state.get("reason"):
        mode += f" ({state['reason']})"
    distance = number(state.get("checkpoint_distance_m"))
    points = number(state.get("route_points"))
    wheel = number(state.get("wheel_cmd_deg"))
    return {
        "mode": Alert(mode) if state.get("mode") == "stopped" else mode,
        "checkpoint": "no route" if points == 0 else
                      f"{fmt_num(state.get('checkpoint'))} of {fmt_num(state.get('route_points'))}",
        "next": "-" if distance is None else
                (f"{distance:.1f} m at {fmt_num(state.get('checkpoint_bearing_deg'), 1)}°, "
                 f"turn {fmt_num(state.get('checkpoint_heading_error_deg'), 1)}°"),
        "cross-track": fmt_unit(state.get("cross_track_m"), "m"),
        "wheel": "-" if wheel is None else f"{wheel:.1f}°",
        **_precision_view(state),
    }


def _precision_view(state: dict) -> dict:
    """The solution judged, and when it is not good enough, why (asking to be noticed)."""
    kind = state.get("precision_kind")
    if not isinstance(kind, str):
        return {}
    age = number(state.get("precision_diff_age_s"))
    text = kind + ("" if age is None else f", corrections {age:.1f} s old")
    if state.get("precision_ok") is False:
        return {"solution": Alert(f"{text}: {state.get('precision_reason') or 'not good enough'}")}
    return {"solution": text}
