"""Twins of the car's Razor with the VIENA firmware: one driven by the simulated car's
truth, one replaying a recording. Both speak exactly what the board sends: boot text after
a reset (opening the port), then 52-byte CRC frames at the firmware's cadence."""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from viena.common.twin.serial_port import ByteTwin
from viena.services.imu.driver.frames import encode_frame
from viena.services.imu.recordings import Recording, load_parked, load_recording
from viena.services.imu.simulator.board import RazorBoard

#: what the firmware prints at boot (VIENA-IST/AHRS src/main.cpp), Serial.println: CR LF
BANNER = ("Initializing I2C devices...", "Testing device connections...",
          "ADXL345 connection successful", "ITG3200 connection successful",
          "HMC5843 connection successful")
BANNER_STEP_S = 0.05
RATE_HZ = 82.5


class RazorTwin(ByteTwin):
    """The board on the simulated car.

    truth      callable returning the latest Truth (`car.truth`)
    board      the sensor model (gains, biases, noise, iron); docs/sensors.md#imu-sensor-models
    boot_s     reset to first frame: the firmware averages the gyro for about 4 s
    delay_s    frames leave this long after they were measured (a slow USB adapter or a
               buffering firmware): the host stamps them late
    line_errors  probability that a frame has one byte damaged on the line (tests)
    keep_sent  remember the last frames sent, as (frame bytes, intact) (tests)
    """

    def __init__(self, truth: Callable | None, board: RazorBoard | None = None, *,
                 rate_hz: float = RATE_HZ, boot_s: float = 4.0, seed: int = 0,
                 delay_s: float = 0.0, line_errors: float = 0.0, keep_sent: int = 0):
        self.truth = truth
        self.board = board or RazorBoard()
        self.period_s = 1.0 / rate_hz
        self.boot_s = boot_s
        self.rng = np.random.default_rng(seed)
        self.line_errors = line_errors
        self.delay_s = delay_s
        self._held: deque[tuple[float, bytes]] = deque()
        self.sent: deque = deque(maxlen=keep_sent)
        self.frames_sent = 0
        self.connects = 0
        self._text: deque[tuple[float, bytes]] = deque()
        self._next_frame: float | None = None

    # -- ByteTwin ---------------------------------------------------------------------------
    def on_connect(self, now_s: float) -> None:
        """Opening the port pulls DTR: the board resets and boots again."""
        self.connects += 1
        self._held.clear()
        self._text = deque((now_s + BANNER_STEP_S * (k + 1), line.encode() + b"\r\n")
                           for k, line in enumerate(BANNER))
        self._next_frame = now_s + self.boot_delay_s

    @property
    def boot_delay_s(self) -> float:
        """From reset to the first frame: the banner, then the gyro averaging."""
        return max(self.boot_s, BANNER_STEP_S * (len(BANNER) + 1))

    def feed(self, data: bytes, now_s: float) -> None:
        """The firmware never reads its serial port."""

    def poll(self, now_s: float) -> bytes:
        out = bytearray()
        while self._text and self._text[0][0] <= now_s:
            out += self._text.popleft()[1]
        if self._next_frame is None:
            return bytes(out)
        if now_s - self._next_frame > 1.0:          # we were not polled for a while: skip
            self._next_frame = now_s
        while self._next_frame <= now_s:
            frame = self.next_frame()
            if frame is None:
                self._next_frame = None
                break
            self._held.append((self._next_frame + self.delay_s, self._on_line(frame)))
            self._next_frame += self.period_s
        while self._held and self._held[0][0] <= now_s:
            out += self._held.popleft()[1]
        return bytes(out)

    def next_due(self, now_s: float) -> float:
        due = [t for t in (self._text[0][0] if self._text else None, self._next_frame,
                           self._held[0][0] if self._held else None) if t is not None]
        return min(due) if due else now_s + 0.05

    # -- frames -----------------------------------------------------------------------------
    def next_frame(self) -> bytes | None:
        if self.truth is None:
            raise TypeError("a RazorTwin without truth has no frames to send: give it `truth`")
        m = self.board.measure(self.truth(), self.rng)
        return encode_frame(self.board.board_id, m.accel_g, m.gyro_dps, m.mag_counts, m.euler_deg)

    def _on_line(self, frame: bytes) -> bytes:
        self.frames_sent += 1
        if self.line_errors and self.rng.random() < self.line_errors:
            damaged = bytearray(frame)
            damaged[int(self.rng.integers(len(frame)))] ^= int(self.rng.integers(1, 256))
            self.sent.append((frame, False))
            return bytes(damaged)
        self.sent.append((frame, True))
        return frame


class RazorReplayTwin(RazorTwin):
    """Replays a recording (the firmware's values, row by row) as firmware frames, with
    the boot banner, at the firmware's cadence; loops at the end unless `loop=False`.
    A reconnect resets the board, but the recording goes on where it was."""

    def __init__(self, recording: Recording | str | Path, *, rate_hz: float = RATE_HZ,
                 boot_s: float = 0.5, loop: bool = True, start: int = 0, **kwargs):
        super().__init__(None, rate_hz=rate_hz, boot_s=boot_s, **kwargs)
        if not isinstance(recording, Recording):
            recording = load_recording(recording)
        if not len(recording):
            raise ValueError(f"recording {recording.name!r} is empty")
        self.recording = recording
        self.loop = loop
        self.row = start
        r = recording
        self._rows = [encode_frame(int(r.board_id[i]) & 0xFF, r.accel_g[i], r.gyro_dps[i],
                                   r.mag_counts[i], np.nan_to_num(r.euler_deg[i]))
                      for i in range(len(r))]

    @classmethod
    def parked(cls, name: str = "nocurrent", **kwargs) -> RazorReplayTwin:
        """One of the real parked-car recordings: nocurrent, speed_0hz, speed_10hz, speed_20hz."""
        return cls(load_parked(name), **kwargs)

    def next_frame(self) -> bytes | None:
        if self.row >= len(self._rows):
            if not self.loop:
                return None
            self.row = 0
        frame = self._rows[self.row]
        self.row += 1
        return frame
