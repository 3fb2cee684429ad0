"""The car's Razor 9DOF (SEN-10125) running the custom VIENA firmware."""
from __future__ import annotations

from viena.services.imu.driver.frames import FRAME_SIZE, DecoderStats, Frame, FrameDecoder
from viena.services.imu.driver.serial_imu import SerialImu


class Razor(SerialImu):
    """Reads 52-byte CRC-checked frames at 500000 baud, about 82.5 per second.

        >>> with Razor("/dev/ttyUSB0") as imu:           # or "socket://127.0.0.1:PORT"
        ...     reading = imu.read(timeout=10)            # boot takes a few seconds
        ...     reading.frame.accel_g, imu.stats, list(imu.board_text)

    The firmware has no commands; opening the port resets the board (DTR), which prints
    its boot text, averages the gyro for a few seconds (keep it still), then streams.
    A frame is handed on once the next one's start (or a frame time of silence) confirms
    it: see frames.py.
    """

    firmware = "viena"
    BAUDRATE = 500_000
    RATE_HZ = 82.5
    FRAME_BYTES = FRAME_SIZE

    def __init__(self, url: str, baudrate: int | None = None, **kwargs):
        super().__init__(url, baudrate, **kwargs)
        self.decoder = FrameDecoder()

    @property
    def stats(self) -> DecoderStats:
        return self.decoder.stats

    @property
    def board_text(self):
        """The most recent lines of text the board printed (its boot banner)."""
        return self.decoder.text

    def _start_stream(self) -> None:
        self.decoder.reset()

    def _decode(self, data: bytes) -> list[tuple[float, int, Frame, int]]:
        return _slots(self.decoder.feed(data))

    def _awaiting_silence(self) -> bool:
        return self.decoder.waiting

    def _decode_silence(self) -> list[tuple[float, int, Frame, int]]:
        return _slots(self.decoder.silence())


def _slots(frames: list[tuple[int, Frame]]) -> list[tuple[float, int, Frame, int]]:
    return [(offset / FRAME_SIZE, offset, frame, offset + FRAME_SIZE) for offset, frame in frames]
