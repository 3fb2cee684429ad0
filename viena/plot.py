"""`viena plot drive.mcap -o drive.png`: a recorded drive as a picture a person can open.

Left, the car's track on a local map (ENU metres): GNSS fixes (one colour per receiver;
each dot is where the receiver's antenna was, not the car's reference point), the
estimator's track and, from the simulator, the truth, with the start, the end and arrows
in the direction of travel. Yaw is unwrapped (a loop adds 360 deg rather than breaking
at +-180), every source aligned on the truth's turns (else the estimator's). Right, over time: speed, yaw
and steering angle from the same sources, and how sure the estimator says it is (its
position's sigma, horizontally and vertically, with, from the simulator, how far off it
really was). The map's origin is the simulator's origin when the recording has truth,
else the estimator's, else the first valid fix, else the route's first checkpoint.
Samples are read defensively: a field a source lacks leaves its line out, never the
picture. Estimator states of either version are read: /2's sigmas (`sigma_h_m`,
`sigma_v_m`), or /1's variances (`enu_var_m2`).

With a pilot (`viena.pilot.path/1` on pilot/path, common/samples/pilot.py), the map
also shows the route it held, through its checkpoints, in the same ENU frame: the newest
route bold, any earlier one faint. With its state (pilot/state), the stretches of the
track where the pilot was following are shaded, and where it stopped is crossed, with why.
"""
from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from viena.common.errors import InputError, SampleError
from viena.common.recording import Source, open_source
from viena.common.samples import topics
from viena.common.samples.fix import NO_FIX_ECEF
from viena.tool import add_drive_arguments

MIN_COURSE_SPEED_MPS = 1.0          # below this a GNSS course over ground is noise


@dataclass
class Series:
    """One source's values over time: t in s since the drive's start, values as columns."""

    t: list = field(default_factory=list)
    rows: list = field(default_factory=list)

    def add(self, t: float, row) -> None:
        self.t.append(t)
        self.rows.append(row)

    def array(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.t, float), np.asarray(self.rows, float)


@dataclass
class Drive:
    """What the plot shows, gathered from a recording; no drawing here."""

    origin: tuple[float, float, float] | None = None
    origin_source: str = ""
    t0: int | None = None
    truth: dict = field(default_factory=lambda: defaultdict(Series))
    estimator: dict = field(default_factory=lambda: defaultdict(Series))
    gnss: dict = field(default_factory=lambda: defaultdict(lambda: defaultdict(Series)))
    steering: dict = field(default_factory=lambda: defaultdict(Series))
    routes: list = field(default_factory=list)      # RouteSeen, oldest first
    pilot: Series = field(default_factory=Series)   # rows: (following 0/1, stopped 0/1)
    pilot_stops: list = field(default_factory=list)  # (t, reason)
    counts: dict = field(default_factory=lambda: defaultdict(int))
    invalid_fixes: int = 0

    def empty(self) -> bool:
        return not (self.truth or self.estimator or self.gnss or self.steering or self.routes)

    def to_map(self) -> None:
        """ECEF series -> ENU at the origin, vectorised (pymap3d takes arrays)."""
        import pymap3d

        for source in [self.truth, *self.gnss.values()]:
            ecef = source.pop("ecef", None)
            if ecef is None or not ecef.t or self.origin is None:
                continue
            t, xyz = ecef.array()
            e, n, u = pymap3d.ecef2enu(xyz[:, 0], xyz[:, 1], xyz[:, 2], *self.origin)
            source["enu"] = Series(list(t), np.column_stack([e, n, u]).tolist())
        for route in self.routes:
            route.to_map(self.origin)


@dataclass
class RouteSeen:
    """A route the pilot held: its checkpoints, when it was last published, and (once
    `to_map`) the checkpoints in the map's ENU metres."""

    lat_deg: tuple
    lon_deg: tuple
    length_m: float | None
    t: float
    enu: np.ndarray | None = None

    def same_as(self, lat_deg, lon_deg) -> bool:
        return self.lat_deg == tuple(lat_deg) and self.lon_deg == tuple(lon_deg)

    def to_map(self, origin) -> None:
        """East, north of the checkpoints at the origin's height (they are places on the
        road, as the pilot takes them)."""
        from viena.services.pilot.model.path import checkpoints_enu

        self.enu = checkpoints_enu(self.lat_deg, self.lon_deg, origin)


def _number(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


def _vec(v, n: int) -> list[float] | None:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        return None
    numbers = [x for x in map(_number, v) if x is not None]
    return numbers if len(numbers) == n else None


#: the topics a plot draws (their names are the kinds load_drive sorts samples by)
PLOTTED = frozenset(t.name for t in (topics.SIM_TRUTH, topics.GNSS_FIX, topics.ESTIMATOR_STATE,
                                     topics.STEERING_STATE, topics.PILOT_PATH, topics.PILOT_STATE))


def _kind(key: str, schema: str) -> str:
    """What a sample is: the topic its schema travels on, or else the topic of its key
    (viena/<car>/...); "" for one not plotted."""
    topic = topics.BY_SCHEMA.get(schema) or topics.RETIRED.get(schema)
    if topic is None:
        parts = key.split("/", 2)
        found = topics.topic_of(parts[2]) if len(parts) == 3 else None
        topic = None if found is None else found[0]
    return topic.name if topic is not None and topic.name in PLOTTED else ""


def load_drive(recording: Source) -> Drive:
    """Two passes: the first finds the drive's start and the map's origin, the second
    gathers the series (positions as ECEF, turned into map coordinates in one go)."""
    drive = Drive()
    first_fix: tuple[float, float, float] | None = None
    first_checkpoint: tuple[float, float, float] | None = None
    for msg in recording.messages():
        kind = _kind(msg.key, msg.schema)
        if not kind:
            continue
        drive.t0 = msg.publish_time if drive.t0 is None else min(drive.t0, msg.publish_time)
        if ((kind == "sim.truth" and drive.origin_source != "simulator origin")
                or (kind == "estimator.state" and drive.origin is None)):
            origin = _vec(_decoded(msg).get("origin"), 3)
            if origin:
                drive.origin = (origin[0], origin[1], origin[2])
                drive.origin_source = "simulator origin" if kind == "sim.truth" else "estimator origin"
        elif kind == "gnss.fix" and first_fix is None:
            s = _decoded(msg)
            geo = _vec([s.get(k) for k in ("lat_deg", "lon_deg", "height_m")], 3)
            if _valid_fix(s) and geo:
                first_fix = (geo[0], geo[1], geo[2])
        elif kind == "pilot.path" and first_checkpoint is None:
            checkpoints = _checkpoints(_decoded(msg))
            if checkpoints:
                first_checkpoint = (checkpoints[0][0], checkpoints[1][0], 0.0)
    if drive.origin is None and first_fix is not None:
        drive.origin, drive.origin_source = first_fix, "first fix"
    if drive.origin is None and first_checkpoint is not None:
        drive.origin, drive.origin_source = first_checkpoint, "the route's first checkpoint"
    add = {"sim.truth": _add_truth, "estimator.state": _add_estimator,
           "gnss.fix": _add_fix, "steering.state": _add_steering,
           "pilot.path": _add_path, "pilot.state": _add_pilot}
    for msg in recording.messages():
        kind = _kind(msg.key, msg.schema)
        if kind and drive.t0 is not None:           # set by the first pass if any kind is there
            s = _decoded(msg)
            t = s["t"] if type(s.get("t")) is int else msg.publish_time
            add[kind](drive, (t - drive.t0) / 1e9, msg.key, s)
    drive.to_map()
    return drive


def _decoded(msg) -> dict:
    try:
        value = msg.value()
    except SampleError:
        return {}
    return value if isinstance(value, dict) else {}


def _valid_fix(s: dict) -> bool:
    ecef = _vec(s.get("ecef_m"), 3)
    return s.get("valid") is not False and ecef is not None and tuple(ecef) != NO_FIX_ECEF


def _yaw_deg(rad: float | None) -> float:
    return math.nan if rad is None else math.degrees(math.atan2(math.sin(rad), math.cos(rad)))


def _add_truth(drive: Drive, t: float, _key: str, s: dict) -> None:
    if not s:
        return
    drive.counts["truth"] += 1
    ecef = _vec(s.get("ecef_m"), 3)
    if ecef:
        drive.truth["ecef"].add(t, ecef)
    if (v := _number(s.get("speed_mps"))) is not None:
        drive.truth["speed"].add(t, v)
    euler = _vec(s.get("euler_rad"), 3)
    if euler:
        drive.truth["yaw"].add(t, _yaw_deg(euler[0]))
    if (v := _number(s.get("wheel_angle_rad"))) is not None:
        drive.truth["wheel"].add(t, math.degrees(v))


def _add_estimator(drive: Drive, t: float, _key: str, s: dict) -> None:
    import pymap3d

    if not s:
        return
    drive.counts["estimator"] += 1
    origin, enu = _vec(s.get("origin"), 3), _vec(s.get("enu_m"), 3)
    if s.get("position_valid") is not False and origin and enu and drive.origin:
        if all(abs(a - b) < 1e-9 for a, b in zip(origin, drive.origin)):
            drive.estimator["enu"].add(t, enu)
        else:                                 # its own origin: through geodetic into ours
            geo = pymap3d.enu2geodetic(*enu, *origin)
            drive.estimator["enu"].add(t, pymap3d.geodetic2enu(*geo, *drive.origin))
    if (v := _number(s.get("speed_mps"))) is not None:
        drive.estimator["speed"].add(t, v)
    if s.get("heading_valid") is not False and (v := _number(s.get("yaw_rad"))) is not None:
        drive.estimator["yaw"].add(t, _yaw_deg(v))
    if s.get("position_valid") is not False:
        sigma = _sigmas(s)
        if sigma:
            drive.estimator["sigma"].add(t, sigma)


def _sigmas(s: dict) -> list[float] | None:
    """[horizontal, vertical] sigma of an estimator state: /2 says them, /1 has variances
    (the larger horizontal one stands in for the ellipse's semi-major axis)."""
    h, v = _number(s.get("sigma_h_m")), _number(s.get("sigma_v_m"))
    if h is not None and v is not None:
        return [h, v]
    var = _vec(s.get("enu_var_m2"), 3)
    if var and min(var) >= 0.0:
        return [math.sqrt(max(var[0], var[1])), math.sqrt(var[2])]
    return None


def _add_fix(drive: Drive, t: float, key: str, s: dict) -> None:
    import pymap3d

    if not s:
        return
    unit = s.get("unit") if isinstance(s.get("unit"), str) else key.split("/")[3]
    drive.counts["gnss"] += 1
    if not _valid_fix(s) or not drive.origin:
        drive.invalid_fixes += 1
        return
    series = drive.gnss[unit]
    series["ecef"].add(t, _vec(s["ecef_m"], 3))
    vel = _vec(s.get("vel_ecef_mps"), 3)
    if vel:
        east, north, _up = pymap3d.ecef2enuv(*vel, drive.origin[0], drive.origin[1])
        speed = math.hypot(east, north)
        series["speed"].add(t, speed)
        if speed >= MIN_COURSE_SPEED_MPS:      # yaw: CCW from north, so course = atan2(-E, N)
            series["yaw"].add(t, math.degrees(math.atan2(-east, north)))


def _checkpoints(s: dict) -> tuple[tuple, tuple] | None:
    """(lat_deg, lon_deg) of a pilot path sample, None unless it is a line of finite points."""
    lat, lon = s.get("lat_deg"), s.get("lon_deg")
    if not isinstance(lat, list) or not isinstance(lon, list) or len(lat) != len(lon) or len(lat) < 2:
        return None
    lat, lon = [_number(v) for v in lat], [_number(v) for v in lon]
    if None in lat or None in lon:
        return None
    return tuple(lat), tuple(lon)


def _add_path(drive: Drive, t: float, _key: str, s: dict) -> None:
    """A route the pilot held (published again every few seconds): each distinct one
    once, in the order they were last held."""
    checkpoints = _checkpoints(s)
    if checkpoints is None or drive.origin is None:
        return
    drive.counts["pilot path"] += 1
    seen = next((r for r in drive.routes if r.same_as(*checkpoints)), None)
    if seen is not None:
        drive.routes.remove(seen)
        seen.t = t
    else:
        seen = RouteSeen(*checkpoints, _number(s.get("length_m")), t)
    drive.routes.append(seen)


def _add_pilot(drive: Drive, t: float, _key: str, s: dict) -> None:
    """Whether the pilot was following, and where it stopped (the first state of a stop)."""
    mode = s.get("mode")
    if not isinstance(mode, str):
        return
    drive.counts["pilot state"] += 1
    was_stopped = bool(drive.pilot.rows) and drive.pilot.rows[-1][1] == 1.0
    drive.pilot.add(t, (float(mode == "following"), float(mode == "stopped")))
    if mode == "stopped" and not was_stopped:
        reason = s.get("reason")
        drive.pilot_stops.append((t, reason if isinstance(reason, str) else ""))


def _add_steering(drive: Drive, t: float, _key: str, s: dict) -> None:
    """Every angle the steering state reports, by the unit in its name: *_deg, *_rad."""
    if not s:
        return
    drive.counts["steering"] += 1
    for name, v in s.items():
        if not isinstance(name, str) or (v := _number(v)) is None:
            continue
        if name.endswith("_deg"):
            drive.steering[name[:-4]].add(t, v)
        elif name.endswith("_rad"):
            drive.steering[name[:-4]].add(t, math.degrees(v))


# -- drawing --------------------------------------------------------------------------------
TRUTH_STYLE: dict[str, Any] = dict(color="black", lw=1.2, label="truth (sim)")
ESTIMATOR_STYLE: dict[str, Any] = dict(color="tab:red", lw=1.2, label="estimator")
GNSS_COLOURS = ["tab:blue", "tab:green", "tab:purple", "tab:orange", "tab:cyan"]
ROUTE_COLOUR = "#e6007e"             # magenta: no source of the track has it (Foxglove's map too)
FOLLOWING_STYLE = dict(color="gold", lw=9, alpha=0.45, solid_capstyle="round", zorder=0.5)
#: a pilot state older than this says nothing about the track (the pilot was not running)
PILOT_STATE_GAP_S = 1.0


def unwrap_deg(deg: np.ndarray) -> np.ndarray:
    """Yaw without its +-180 breaks: each step the shortest turn, so a loop of the track
    is a ramp of 360 deg rather than a saw tooth."""
    return np.degrees(np.unwrap(np.radians(deg))) if len(deg) else deg


def align_deg(t: np.ndarray, deg: np.ndarray, t_ref: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """An unwrapped yaw shifted by whole turns onto a reference one (the truth, or the
    estimator), so that two sources of the same heading draw on top of each other."""
    if not len(deg) or not len(ref):
        return deg
    turns = np.round(np.median(np.interp(t, t_ref, ref) - deg) / 360.0)
    return deg + 360.0 * turns


def draw(drive: Drive, title: str, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(15, 11), dpi=100, layout="constrained")
    grid = fig.add_gridspec(4, 2, width_ratios=[1.15, 1])
    track = fig.add_subplot(grid[:, 0])
    speed = fig.add_subplot(grid[0, 1])
    yaw = fig.add_subplot(grid[1, 1], sharex=speed)
    steer = fig.add_subplot(grid[2, 1], sharex=speed)
    sigma = fig.add_subplot(grid[3, 1], sharex=speed)
    fig.suptitle(title, fontsize=12)

    yaw_ref = _yaw_reference(drive)
    _draw_routes(track, drive)
    _draw_gnss(track, speed, yaw, drive, yaw_ref)
    for source, style in ((drive.truth, TRUTH_STYLE), (drive.estimator, ESTIMATOR_STYLE)):
        _draw_source(track, speed, yaw, source, style, yaw_ref)
    _draw_steering(steer, drive)
    _draw_sigma(sigma, drive)
    _mark_ends(track, drive)
    _draw_pilot(track, drive)
    _label_axes(track, speed, yaw, steer, sigma, drive)
    for ax in (speed, yaw, steer):
        plt.setp(ax.get_xticklabels(), visible=False)
    fig.savefig(path, format="png")
    plt.close(fig)


def _draw_gnss(track, speed, yaw, drive: Drive, yaw_ref) -> None:
    """Each GNSS unit's points: where its antenna was (not the car's centre), its speed, its yaw."""
    for unit, colour in zip(sorted(drive.gnss), GNSS_COLOURS * 4):
        series = drive.gnss[unit]
        style: dict[str, Any] = dict(color=colour, label=f"GNSS {unit}")
        if series["enu"].t:
            _, enu = series["enu"].array()
            track.plot(enu[:, 0], enu[:, 1], ".", ms=3, alpha=0.5, color=colour,
                       label=f"GNSS {unit}: antenna positions")
        if series["speed"].t:
            speed.plot(*series["speed"].array(), ".", ms=2, alpha=0.6, **style)
        if series["yaw"].t:
            t, deg = series["yaw"].array()
            yaw.plot(t, align_deg(t, unwrap_deg(deg), *yaw_ref), ".", ms=2, alpha=0.6, **style)


def _draw_source(track, speed, yaw, source: dict, style: dict[str, Any], yaw_ref) -> None:
    """The truth's or the estimator's lines: track, speed, yaw."""
    if source["enu"].t:
        _, enu = source["enu"].array()
        track.plot(enu[:, 0], enu[:, 1], "-", **style)
    if source["speed"].t:
        speed.plot(*source["speed"].array(), "-", **style)
    if source["yaw"].t:
        t, deg = source["yaw"].array()
        yaw.plot(t, align_deg(t, unwrap_deg(deg), *yaw_ref), "-", **style)


def _draw_steering(ax, drive: Drive) -> None:
    """The wheel angle: the truth's, and each steering's."""
    if drive.truth["wheel"].t:
        ax.plot(*drive.truth["wheel"].array(), "-", **TRUTH_STYLE)
    for name, colour in zip(sorted(drive.steering), ["tab:orange", "tab:purple", "tab:olive", "tab:brown"] * 4):
        ax.plot(*drive.steering[name].array(), "-", lw=1, color=colour, label=f"steering {name}")


def _label_axes(track, speed, yaw, steer, sigma, drive: Drive) -> None:
    """Titles, units, the map's origin, grids and legends ("no data" on an empty plot)."""
    import matplotlib.ticker  # yaw's axis: a tick every 90 deg

    track.set_aspect("equal", adjustable="datalim")
    origin = drive.origin
    where = (f"{origin[0]:.5f}, {origin[1]:.5f}, {origin[2]:.0f} m ({drive.origin_source})"
             if origin else "no position")
    track.set(title="track", xlabel="east [m]", ylabel="north [m]")
    track.text(0.01, 0.01, f"origin {where}", transform=track.transAxes, fontsize=8, color="0.4")
    speed.set(title="speed", ylabel="m/s")
    yaw.set(title="yaw (counter-clockwise from north, unwrapped: +360 per left-hand loop)", ylabel="deg")
    yaw.yaxis.set_major_locator(matplotlib.ticker.MultipleLocator(90))
    steer.set(title="steering (wheel angle)", ylabel="deg")
    sigma.set(title="estimator: position sigma (and, simulated, its true error)", ylabel="m",
              xlabel="time since start [s]")
    for ax in (track, speed, yaw, steer, sigma):
        ax.grid(True, alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        if handles:
            ax.legend(fontsize=8, loc="best", markerscale=2.5)
        elif ax is not track:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", color="0.5")


def _draw_sigma(ax, drive: Drive) -> None:
    """The estimator's horizontal and vertical sigma; with the truth, its horizontal error."""
    if not drive.estimator["sigma"].t:
        return
    t, sig = drive.estimator["sigma"].array()
    ax.plot(t, sig[:, 0], "-", color="tab:red", lw=1.2, label="σ horizontal (semi-major)")
    ax.plot(t, sig[:, 1], "--", color="tab:red", lw=1, label="σ vertical")
    if drive.truth["enu"].t and drive.estimator["enu"].t:
        t_true, true = drive.truth["enu"].array()
        t_est, est = drive.estimator["enu"].array()
        e = np.interp(t_est, t_true, true[:, 0]) - est[:, 0]
        n = np.interp(t_est, t_true, true[:, 1]) - est[:, 1]
        ax.plot(t_est, np.hypot(e, n), "-", color="black", lw=0.8, alpha=0.7,
                label="true horizontal error (sim)")


def _yaw_reference(drive: Drive) -> tuple[np.ndarray, np.ndarray]:
    """The unwrapped yaw the others are aligned to: the truth's, else the estimator's."""
    for source in (drive.truth, drive.estimator):
        if source["yaw"].t:
            t, deg = source["yaw"].array()
            return t, unwrap_deg(deg)
    return np.array([]), np.array([])


def _main_series(drive: Drive) -> tuple[np.ndarray, np.ndarray] | None:
    """The track the marks go on: the truth, else the estimator, else a receiver (t, x y rows)."""
    for series in [drive.truth["enu"], drive.estimator["enu"], *(g["enu"] for g in drive.gnss.values())]:
        if series.t:
            return np.asarray(series.t, float), np.asarray(series.rows, float)[:, :2]
    return None


def _main_track(drive: Drive) -> np.ndarray | None:
    series = _main_series(drive)
    return None if series is None else series[1]


def _draw_routes(ax, drive: Drive) -> None:
    """The routes the pilot held, checkpoints marked: the newest bold, earlier ones faint."""
    earlier = drive.routes[:-1]
    for i, route in enumerate(earlier):
        ax.plot(route.enu[:, 0], route.enu[:, 1], "--", marker="D", ms=3, lw=1.2, alpha=0.35,
                color=ROUTE_COLOUR, label="pilot route, earlier" if i == 0 else None, zorder=1)
    if drive.routes:
        route = drive.routes[-1]
        length = "" if route.length_m is None else f", {route.length_m:.0f} m"
        ax.plot(route.enu[:, 0], route.enu[:, 1], "--", marker="D", ms=4, lw=2, mfc="white",
                color=ROUTE_COLOUR, label=f"pilot route ({len(route.enu)} checkpoints{length})", zorder=1)


def pilot_following(t: np.ndarray, pilot_t: np.ndarray, following: np.ndarray) -> np.ndarray:
    """At each time of `t`, whether the pilot's newest state (no older than
    PILOT_STATE_GAP_S) said it was following."""
    i = np.searchsorted(pilot_t, t, side="right") - 1
    known = (i >= 0) & (t - pilot_t[np.maximum(i, 0)] <= PILOT_STATE_GAP_S)
    return known & (following[np.maximum(i, 0)] > 0.5)


def _draw_pilot(ax, drive: Drive) -> None:
    """The track shaded where the pilot followed the route; a cross where it stopped, with why."""
    series = _main_series(drive)
    if series is None or not drive.pilot.t:
        return
    t, xy = series
    pilot_t, rows = drive.pilot.array()
    on = pilot_following(t, pilot_t, rows[:, 0])
    if on.any():
        shaded = np.where(on[:, None], xy, np.nan)        # NaN breaks the line where it did not follow
        ax.plot(shaded[:, 0], shaded[:, 1], "-", label="pilot following", **FOLLOWING_STYLE)
    middle = np.nanmean(xy[:, 0])
    for i, (t_stop, reason) in enumerate(drive.pilot_stops):
        x, y = np.interp(t_stop, t, xy[:, 0]), np.interp(t_stop, t, xy[:, 1])
        ax.plot([x], [y], "X", ms=7, color=ROUTE_COLOUR, mec="0.1", label="pilot stopped" if i == 0 else None)
        left = x > middle                      # the text towards the map's middle, not off its edge
        ax.annotate(f"stopped: {reason}" if reason else "stopped", (x, y), xytext=(-8 if left else 8, 6),
                    textcoords="offset points", ha="right" if left else "left", fontsize=8, color=ROUTE_COLOUR)


def _mark_ends(ax, drive: Drive, arrows: int = 10) -> None:
    """Start (open circle), end (filled square) and, along the way, arrows every so many
    metres in the direction of travel."""
    xy = _main_track(drive)
    if xy is None:
        return
    for (x, y), text, marker in ((xy[0], "start", dict(marker="o", mfc="none")),
                                 (xy[-1], "end", dict(marker="s", mfc="0.2"))):
        ax.plot([x], [y], ms=9, mec="0.2", mew=1.5, ls="none", **marker)
        ax.annotate(text, (x, y), xytext=(8, -12), textcoords="offset points", fontsize=9, color="0.2")
    for tail, head in direction_arrows(xy, arrows):
        ax.annotate("", head, xytext=tail, arrowprops=dict(arrowstyle="-|>", color="0.2", lw=1.2,
                                                           mutation_scale=14))


def direction_arrows(xy: np.ndarray, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(tail, head) of `count` short arrows spread evenly by distance along a track, each
    pointing the way the car went; none if it hardly moved."""
    steps = np.hypot(*np.diff(xy, axis=0).T)
    along = np.concatenate([[0.0], np.cumsum(steps)])
    length = along[-1] if len(along) else 0.0
    if length < 1.0:
        return []
    out = []
    for d in length * (np.arange(count) + 0.5) / count:
        i = int(np.searchsorted(along, d))
        j = int(np.searchsorted(along, min(d + 0.02 * length, length)))
        if j > i:
            out.append((xy[max(i - 1, 0)], xy[j]))
    return out


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="viena plot", description=__doc__)
    add_drive_arguments(parser)
    parser.add_argument("-o", "--output", metavar="PNG", type=Path, default=None,
                        help="the picture to write (default: the recording's name with .png)")
    return parser


def run(args: argparse.Namespace) -> int:
    try:
        recording = open_source(args.file, args.drive, say=lambda note: print(f"viena plot: {note}", file=sys.stderr))
        drive = load_drive(recording)
    except InputError as exc:
        print(f"viena plot: {exc}", file=sys.stderr)
        return 2
    output = args.output or recording.path.with_suffix(".png")
    for line in recording.report():
        print(f"viena plot: {recording.path}: {line}", file=sys.stderr)
    if drive.empty():
        print(f"viena plot: {recording.path}: nothing to plot (no truth, GNSS, estimator or "
              f"steering samples)", file=sys.stderr)
        return 1
    duration = 0.0
    if recording.first_log_time is not None and recording.last_log_time is not None:
        duration = (recording.last_log_time - recording.first_log_time) / 1e9
    counts = ", ".join(f"{n} {k}" for k, n in drive.counts.items())
    if drive.invalid_fixes:
        counts += f" ({drive.invalid_fixes} fixes without a position)"
    title = f"{recording.path.name}: {duration:.1f} s, {counts}"
    try:
        draw(drive, title, output)
    except OSError as exc:
        print(f"viena plot: cannot write {output}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"wrote {output}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
