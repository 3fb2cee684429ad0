"""`viena plot` with a pilot (issue 17): the route it held on the map, in the frame of the
track, checkpoints marked; where it followed and where it stopped. Read off the figure's
artists, not its pixels."""
from __future__ import annotations

import numpy as np
import pymap3d
import pytest
from laptop_helpers import TRUTH_KEY, write_drive
from pilot_drive import checkpoints_of, geojson_route, write_pilot_drive

from viena.common.recording import Recording
from viena.plot import PILOT_STATE_GAP_S, draw, load_drive, pilot_following

SECONDS = 20.0
STOP_REASON = "cross-track error 3.1 m > 2.0 m"


@pytest.fixture
def figure(monkeypatch):
    """draw() a recording; its figure kept to look at (plt.close would drop it)."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)

    def make(path):
        draw(load_drive(Recording(path)), "drive", path.with_suffix(".png"))
        assert path.with_suffix(".png").stat().st_size > 0
        return kept[-1].axes[0]                                  # the map
    return make


def labelled(track, start: str):
    return [line for line in track.lines if line.get_label().startswith(start)]


@pytest.mark.slow  # matplotlib draws a whole drive
def test_the_route_is_drawn_through_its_checkpoints_on_the_track(tmp_path, figure):
    plain = write_drive(tmp_path / "plain.mcap", seconds=SECONDS)
    points = checkpoints_of(plain[TRUTH_KEY], every_s=2.0)
    path = tmp_path / "drive.mcap"
    written = write_pilot_drive(path, SECONDS, [(1.0, geojson_route(points))],
                                [(5.0, "following", None), (15.0, "stopped", STOP_REASON)])
    track = figure(path)
    route = written["routes"][0]
    [line] = labelled(track, "pilot route (")
    assert line.get_label() == f"pilot route ({len(points)} checkpoints, {route.length_m:.0f} m)"
    assert line.get_marker() == "D" and line.get_linestyle() == "--"   # checkpoints marked, its own style
    origin = plain[TRUTH_KEY][0]["origin"]                               # the map's origin: the simulator's
    lat, lon = np.array(points).T
    east, north, _ = pymap3d.geodetic2enu(lat, lon, np.full_like(lat, origin[2]), *origin)
    assert np.allclose(line.get_xdata(), east, atol=1e-6) and np.allclose(line.get_ydata(), north, atol=1e-6)
    truth = next(line for line in track.lines if line.get_label() == "truth (sim)")
    truth_xy = np.column_stack([truth.get_xdata(), truth.get_ydata()])
    for x, y in zip(east, north):                                        # on the track it was made from
        assert np.hypot(*(truth_xy - (x, y)).T).min() < 0.05
    assert "pilot route (" in " ".join(track.get_legend_handles_labels()[1])

    [following] = labelled(track, "pilot following")                     # shaded from 5 s to 15 s
    shaded = ~np.isnan(np.asarray(following.get_xdata(), float))
    t = np.array([s["t"] for s in plain[TRUTH_KEY]]) / 1e9
    t -= t[0]
    assert shaded.sum() == pytest.approx(((t >= 5.0) & (t < 15.0)).sum(), abs=10)
    assert not shaded[t < 4.9].any() and not shaded[t > 15.1].any()
    [stopped] = labelled(track, "pilot stopped")
    assert np.hypot(stopped.get_xdata()[0] - np.interp(15.0, t, truth.get_xdata()),
                    stopped.get_ydata()[0] - np.interp(15.0, t, truth.get_ydata())) < 0.5
    assert f"stopped: {STOP_REASON}" in [text.get_text() for text in track.texts]


@pytest.mark.slow  # matplotlib draws a whole drive
def test_a_new_route_is_drawn_bold_and_the_earlier_one_faint(tmp_path, figure):
    plain = write_drive(tmp_path / "plain.mcap", seconds=SECONDS)
    first = checkpoints_of(plain[TRUTH_KEY], every_s=2.0)
    second = checkpoints_of(plain[TRUTH_KEY], every_s=4.0, offset_m=3.0)
    path = tmp_path / "drive.mcap"
    write_pilot_drive(path, SECONDS, [(1.0, geojson_route(first)), (8.0, geojson_route(second))])
    track = figure(path)
    [newest] = labelled(track, "pilot route (")
    [earlier] = labelled(track, "pilot route, earlier")
    assert len(newest.get_xdata()) == len(second) and len(earlier.get_xdata()) == len(first)
    assert earlier.get_alpha() < (newest.get_alpha() or 1.0)
    assert not labelled(track, "pilot following") and not labelled(track, "pilot stopped")   # no state


@pytest.mark.slow  # matplotlib draws a whole drive
def test_a_recording_without_a_pilot_plots_as_before(tmp_path, figure):
    path = tmp_path / "drive.mcap"
    write_drive(path, seconds=5.0)
    track = figure(path)
    assert not labelled(track, "pilot")
    assert sorted(track.get_legend_handles_labels()[1]) == ["GNSS gnss0: antenna positions", "estimator",
                                                            "truth (sim)"]


def test_following_is_the_newest_state_and_only_while_states_come():
    pilot_t = np.array([0.0, 1.0, 2.0, 10.0])
    following = np.array([0.0, 1.0, 0.0, 1.0])
    t = np.array([-1.0, 0.5, 1.0, 1.5, 2.5, 2.0 + PILOT_STATE_GAP_S + 0.1, 10.2])
    assert pilot_following(t, pilot_t, following).tolist() == [False, False, True, True, False, False, True]
