"""The plot's fixes of issue 16: yaw without +-180 breaks, where the drive ended and which
way it went, and GNSS dots named for what they are (antenna positions)."""
from __future__ import annotations

import numpy as np
import pytest
from laptop_helpers import write_drive

from viena.common.recording import Recording
from viena.plot import align_deg, direction_arrows, draw, load_drive, unwrap_deg


def test_yaw_through_south_is_one_ramp_not_a_saw_tooth():
    turning = np.arange(0.0, 800.0, 7.0)                     # two and more left-hand loops
    wrapped = (turning + 180.0) % 360.0 - 180.0
    assert np.abs(np.diff(wrapped)).max() > 300              # what the old plot drew
    assert np.allclose(unwrap_deg(wrapped), turning)
    t = np.arange(len(turning), dtype=float)
    late = unwrap_deg(wrapped[10:]) - 360.0                  # joined a turn later, off by one turn
    assert np.allclose(align_deg(t[10:], late, t, turning), turning[10:])


def test_arrows_point_the_way_the_car_went():
    angle = np.linspace(0, 1.5 * np.pi, 300)                 # counter-clockwise, 3/4 of a circle
    xy = np.column_stack([10 * np.cos(angle), 10 * np.sin(angle)])
    arrows = direction_arrows(xy, 6)
    assert len(arrows) == 6
    for tail, head in arrows:
        step = head - tail
        tangent = np.array([-tail[1], tail[0]])              # counter-clockwise at the tail
        assert step @ tangent > 0
    assert direction_arrows(np.zeros((50, 2)), 6) == []      # parked: no direction to show


@pytest.mark.slow  # matplotlib draws a whole drive
def test_the_picture_marks_the_end_and_names_gnss_dots_as_antenna_positions(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    path = tmp_path / "drive.mcap"
    write_drive(path, seconds=55.0)
    figures = []
    monkeypatch.setattr(plt, "close", figures.append)         # keep the figure to look at
    draw(load_drive(Recording(path)), "drive", tmp_path / "drive.png")
    track, _speed, yaw = figures[0].axes[:3]
    assert "GNSS gnss0: antenna positions" in track.get_legend_handles_labels()[1]
    texts = [t.get_text() for t in track.texts]
    assert "start" in texts and "end" in texts
    assert sum(1 for t in track.texts if getattr(t, "arrow_patch", None) is not None and not t.get_text()) == 10
    truth = next(line for line in yaw.lines if line.get_label() == "truth (sim)")
    assert np.abs(np.diff(truth.get_ydata())).max() < 30     # no break, though the car turned
    assert np.ptp(truth.get_ydata()) > 360
