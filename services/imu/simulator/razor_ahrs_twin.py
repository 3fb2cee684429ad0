"""Twin of a Razor running the stock Razor AHRS firmware (v1.4.2): its command parser,
output modes and 50 Hz stream, from the same board model as the VIENA-firmware twin.

After a reset the firmware streams `#YPR=...` text (its start-up mode) until told
otherwise; during the first `boot_s` the bootloader swallows whatever the host writes.
"""
from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable

import numpy as np

from viena.common.twin.serial_port import ByteTwin
from viena.services.imu.driver.razor_ahrs import from_board, sync_reply
from viena.services.imu.model.firmware_units import DEFAULT_MAGN_SCALE
from viena.services.imu.simulator.board import RazorBoard

RATE_HZ = 50.0
_SENSOR_MODES = {b"r": "raw", b"c": "calibrated", b"b": "both"}


def _text3(label: bytes, v) -> bytes:
    return label + b"=" + b",".join(b"%.2f" % x for x in v) + b"\r\n"


class RazorAhrsTwin(ByteTwin):
    def __init__(self, truth: Callable, board: RazorBoard | None = None, *,
                 rate_hz: float = RATE_HZ, boot_s: float = 0.5, seed: int = 0,
                 magn_scale: float = DEFAULT_MAGN_SCALE):
        self.truth = truth
        self.board = board or RazorBoard()
        self.period_s = 1.0 / rate_hz
        self.boot_s = boot_s
        self.magn_scale = magn_scale
        self.rng = np.random.default_rng(seed)
        self.connects = 0
        self.commands: list[bytes] = []        # what the host asked for, for tests
        self.swallowed = 0                     # bytes the bootloader ate
        self._reset(None)

    def _reset(self, now_s: float | None) -> None:
        self.stream_on = True
        self.mode, self.binary = "angles", False
        self._single = False
        self._input = bytearray()
        self._out: deque[bytes] = deque()
        self._booted_at = None if now_s is None else now_s + self.boot_s
        self._next_frame = self._booted_at

    # -- ByteTwin ---------------------------------------------------------------------------
    def on_connect(self, now_s: float) -> None:
        self.connects += 1
        self._reset(now_s)

    def feed(self, data: bytes, now_s: float) -> None:
        if self._booted_at is None or now_s < self._booted_at:
            self.swallowed += len(data)             # the bootloader eats it
            return
        self._input += data
        self._parse()

    def poll(self, now_s: float) -> bytes:
        out = bytearray()
        while self._out:
            out += self._out.popleft()
        if self._next_frame is None:
            return bytes(out)
        if now_s - self._next_frame > 1.0:
            self._next_frame = now_s
        while self._next_frame <= now_s:
            if self.stream_on or self._single:
                out += self._frame()
                self._single = False
            self._next_frame += self.period_s
        return bytes(out)

    def next_due(self, now_s: float) -> float:
        if self._out:
            return now_s
        return self._next_frame if self._next_frame is not None else now_s + 0.05

    # -- the firmware's loop(): '#' then a command letter, parameters read blocking ----------
    def _parse(self) -> None:
        buf = self._input
        while len(buf) >= 2:
            if buf[0] != ord("#"):
                del buf[0]
                continue
            cmd = bytes(buf[1:2])
            need = {b"s": 4, b"o": 3}.get(cmd, 2)
            if cmd == b"o" and len(buf) >= 3:
                need = {b"s": 5, b"e": 4}.get(bytes(buf[2:3]), 3)
            if len(buf) < need:
                return
            command = bytes(buf[:need])
            del buf[:need]
            self.commands.append(command)
            self._command(command)

    def _command(self, c: bytes) -> None:
        if c == b"#f":
            self._single = True
        elif c.startswith(b"#s"):
            self._out.append(sync_reply(c[2:4]))
        elif c in (b"#o0", b"#o1"):
            self.stream_on = c == b"#o1"
        elif c == b"#ot" or c == b"#ob":
            self.mode, self.binary = "angles", c == b"#ob"
        elif c.startswith(b"#os"):
            mode = _SENSOR_MODES.get(c[3:4])
            if mode:
                self.mode = mode
            if c[4:5] in (b"t", b"b"):
                self.binary = c[4:5] == b"b"
        # '#oe', '#oc', '#on', '#ox' and anything unknown: no effect on what we model

    # -- output ------------------------------------------------------------------------------
    def _frame(self) -> bytes:
        m = self.board.measure(self.truth(), self.rng)
        if self.mode == "angles":
            yaw, pitch, roll = m.euler_deg
            ypr = (-yaw, -pitch, roll)              # its frame: X forward, Y right, Z down
            if self.binary:
                return struct.pack("<3f", *ypr)
            return _text3(b"#YPR", ypr)
        calibrated = from_board(m.accel_g, m.gyro_dps, [c * self.magn_scale for c in m.mag_counts])
        raw_acc = (m.accel_lsb[1], m.accel_lsb[0], m.accel_lsb[2])
        raw = (raw_acc, from_board((0, 0, 0), m.gyro_dps, m.mag_counts)[1],
               calibrated[2])
        blocks = {"raw": [(raw, b"R")], "calibrated": [(calibrated, b"C")],
                  "both": [(raw, b"R"), (calibrated, b"C")]}[self.mode]
        out = bytearray()
        for (acc, mag, gyr), tag in blocks:
            if self.binary:
                out += struct.pack("<9f", *acc, *mag, *gyr)
            else:
                out += _text3(b"#A-" + tag, acc) + _text3(b"#M-" + tag, mag) + _text3(b"#G-" + tag, gyr)
        return bytes(out)
