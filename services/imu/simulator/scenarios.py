"""Scripted motions of the board, run through a twin on a synthetic clock: the frames a
calibration would be made from, produced without sockets or waiting.

    rec = record_twin(RazorTwin(None, board), six_poses())   # the six resting poses
    rec = record_twin(RazorTwin(None, board), turning())     # a car driving in circles

The twin's bytes go through the real decoder, so a scenario recording holds exactly what
the driver would deliver from the board.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from viena.common import clock
from viena.common.geodesy import normal_gravity
from viena.common.rotation import quat_from_euler, quat_to_matrix
from viena.services.imu.driver.frames import FrameDecoder
from viena.services.imu.recordings import Recording
from viena.services.sim.model.truth import IST_ORIGIN, Truth

#: attitude (yaw, pitch, roll) that puts each body axis up: '+x' reads +1 g on x
POSE_EULER = {"+z": (0.0, 0.0, 0.0), "-z": (0.0, 0.0, math.pi),
              "+x": (0.0, -math.pi / 2, 0.0), "-x": (0.0, math.pi / 2, 0.0),
              "+y": (0.0, 0.0, math.pi / 2), "-y": (0.0, 0.0, -math.pi / 2)}

Motion = Callable[[float], tuple[float, float, float]]     # t -> (yaw, pitch, roll)


class Script:
    """A truth source for a twin: the attitude is a function of the script's clock."""

    def __init__(self, motion: Motion, duration_s: float, gravity: float | None = None,
                 t0_ns: int | None = None):
        self.motion, self.duration_s = motion, duration_s
        self.gravity = normal_gravity(IST_ORIGIN[0], IST_ORIGIN[2]) if gravity is None else gravity
        self.t0_ns = clock.time_ns() if t0_ns is None else t0_ns
        self.now = 0.0

    def __call__(self) -> Truth:
        t, dt = self.now, 1e-3
        q = quat_from_euler(*self.motion(t))
        r0, r1 = quat_to_matrix(quat_from_euler(*self.motion(t - dt))), quat_to_matrix(q)
        omega = r1.T @ (r1 - r0) / dt                        # skew(w), w in body axes
        w = np.array([omega[2, 1] - omega[1, 2], omega[0, 2] - omega[2, 0], omega[1, 0] - omega[0, 1]]) / 2
        zero = np.zeros(3)
        return Truth(self.t0_ns + int(t * 1e9), t, IST_ORIGIN, zero, zero, zero, q, w, 0.0, 0.0,
                     self.gravity)


def fixed_truth(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0, gyro=(0.0, 0.0, 0.0),
                gravity: float | None = None) -> Truth:
    """The car standing with this attitude (rad) and angular rate (rad/s, body axes)."""
    zero = np.zeros(3)
    g = normal_gravity(IST_ORIGIN[0], IST_ORIGIN[2]) if gravity is None else gravity
    return Truth(clock.time_ns(), 0.0, IST_ORIGIN, zero, zero, zero, quat_from_euler(yaw, pitch, roll),
                 np.array(gyro, float), 0.0, 0.0, g)


def record_twin(twin, script: Script) -> Recording:
    """Run `twin` over the script (after its boot) and decode what it sends."""
    twin.truth = script
    decoder = FrameDecoder()
    frames, times = [], []
    start = 0.0
    twin.on_connect(start)
    step = twin.period_s
    t = start
    while True:
        t += step
        script.now = t - start - getattr(twin, "boot_delay_s", twin.boot_s)
        if script.now > script.duration_s:
            break
        # the board sends a frame, then the line is quiet until the next one
        for _, frame in decoder.feed(twin.poll(t)) + decoder.silence():
            frames.append(frame)
            times.append(script.t0_ns + int(script.now * 1e9))
    if not frames:
        return Recording(np.zeros(0, np.int64), np.zeros(0, int), *(np.zeros((0, 3)),) * 4, "twin")
    return Recording(np.array(times, np.int64), np.array([f.board_id or 0 for f in frames]),
                     np.array([f.accel_g for f in frames]), np.array([f.gyro_dps for f in frames]),
                     np.array([f.mag_counts for f in frames]),
                     np.array([f.euler_deg or (math.nan,) * 3 for f in frames]), "twin")


# -- motions --------------------------------------------------------------------------------------
def six_poses(hold_s: float = 3.0, move_s: float = 1.5, order=("+z", "-z", "+x", "-x", "+y", "-y"),
              **kwargs) -> Script:
    """Rest in each pose for hold_s, turning to the next over move_s."""
    period = hold_s + move_s

    def motion(t: float):
        k = min(int(max(t, 0.0) // period), len(order) - 1)
        tau = max(t, 0.0) - k * period
        a = np.array(POSE_EULER[order[k]])
        if tau <= hold_s or k == len(order) - 1:
            return tuple(a)
        b = np.array(POSE_EULER[order[k + 1]])
        s = (tau - hold_s) / move_s
        return tuple(a + (b - a) * (3 * s * s - 2 * s ** 3))
    return Script(motion, len(order) * period - move_s, **kwargs)


def still(seconds: float = 10.0, yaw: float = 0.3, pitch: float = 0.0, roll: float = 0.0, **kwargs) -> Script:
    return Script(lambda t: (yaw, pitch, roll), seconds, **kwargs)


def turning(turns: float = 2.0, period_s: float = 20.0, pitch: float = 0.0, roll: float = 0.0,
            **kwargs) -> Script:
    """The car driving in circles on level ground (what the 2-D ellipse method needs)."""
    return Script(lambda t: (2 * math.pi * t / period_s, pitch, roll), turns * period_s, **kwargs)


def tumbling(seconds: float = 90.0, **kwargs) -> Script:
    """The board turned through every orientation (for the 3-D ellipsoid fit)."""
    def motion(t: float):
        return (2 * math.pi * t / 7.0, 1.3 * math.sin(2 * math.pi * t / 23.0),
                math.pi * math.sin(2 * math.pi * t / 31.0))
    return Script(motion, seconds, **kwargs)
