"""The stock Razor AHRS firmware (Razor-AHRS/razor-9dof-ahrs v1.4.2), for boards that run it.

57600 baud, one output frame per 20 ms. Commands are ASCII, no line ends needed:
`#o0`/`#o1` stream off/on, `#oscb` calibrated sensors as binary (9 little-endian floats:
acc x/y/z, mag x/y/z, gyr x/y/z = 36 bytes, no sync, no checksum), `#osct` the same as
text lines `#A-C=x,y,z` `#M-C=..` `#G-C=..`, `#oe0` error messages off, `#s<xy>` asks
for the token `#SYNCH<xy>\\r\\n`, after which binary frames start on a boundary.

The firmware's own axes are X forward (towards the connector edge), Y right, Z down, its
accelerometer output is the gravity vector (the negated specific force) with 1 g = 256,
and its gyro output is in ITG-3200 counts. The driver turns all of it back into the
board's printed axes and the units the VIENA firmware uses, so one `Frame` serves both.

Binary frames carry neither sync nor checksum: a lost or extra byte shifts every frame
after it, and when the shift is a whole number of floats the shifted frames hold real
values in the wrong fields and look possible. The firmware writes each frame in one go and
pauses until the next, so the line's pause is the boundary the bytes lack: binary frames
are held until the line falls silent for a frame time, and accepted only if the pause
falls on a frame boundary; part of a frame at a pause, or an impossible frame, drops the
synchronisation until a new token. Over a link that hands bytes over without pauses,
frames beyond MAX_HELD are let go while the frames after them are possible, which a
shift by whole floats passes: there, the text output is the safer choice.
"""
from __future__ import annotations

import itertools
import struct
from dataclasses import dataclass

import serial

from viena.common import clock
from viena.services.imu.driver.frames import Frame
from viena.services.imu.driver.serial_imu import SerialImu
from viena.services.imu.model.firmware_units import ACCEL_PER_G, GYRO_LSB_PER_DPS

BAUDRATE = 57_600
RATE_HZ = 50.0
STREAM_OFF = b"#o0"
STREAM_ON = b"#o1"
CALIBRATED_BINARY = b"#oscb"
CALIBRATED_TEXT = b"#osct"
ERRORS_OFF = b"#oe0"
SENSORS = struct.Struct("<9f")
#: binary frames held while waiting for the line's pause (160 ms at 50 Hz)
MAX_HELD = 8
#: What the board can physically send, in the firmware's units (see frames.LIMITS): the
#: ADXL345 to 18 g, the calibrated magnetometer (the HMC5843's int16 registers, a glitch
#: included, times MAGN_SCALE 100/600, with room for another calibration), the ITG-3200's
#: int16 counts less the boot bias.
_LIMITS = (18 * ACCEL_PER_G,) * 3 + (1.0e4,) * 3 + (2300 * GYRO_LSB_PER_DPS,) * 3


def sync_request(token: bytes) -> bytes:
    return b"#s" + token


def sync_reply(token: bytes) -> bytes:
    return b"#SYNCH" + token + b"\r\n"


def to_board(acc, mag, gyr) -> Frame:
    """Firmware axes and units -> the board's axes: g, deg/s, magnetometer units."""
    return Frame(
        None,
        (acc[1] / ACCEL_PER_G, acc[0] / ACCEL_PER_G, acc[2] / ACCEL_PER_G),
        (-gyr[1] / GYRO_LSB_PER_DPS, -gyr[0] / GYRO_LSB_PER_DPS, -gyr[2] / GYRO_LSB_PER_DPS),
        (-mag[1], -mag[0], -mag[2]),
        None)


def from_board(accel_g, gyro_dps, mag) -> tuple[tuple, tuple, tuple]:
    """The inverse of `to_board`: what the firmware sends for board-axis values."""
    acc = (accel_g[1] * ACCEL_PER_G, accel_g[0] * ACCEL_PER_G, accel_g[2] * ACCEL_PER_G)
    mag_fw = (-mag[1], -mag[0], -mag[2])
    gyr = (-gyro_dps[1] * GYRO_LSB_PER_DPS, -gyro_dps[0] * GYRO_LSB_PER_DPS,
           -gyro_dps[2] * GYRO_LSB_PER_DPS)
    return acc, mag_fw, gyr


@dataclass
class AhrsStats:
    frames: int = 0
    bad_frames: int = 0        # binary frames with impossible values, text lines that do not parse
    unconfirmed: int = 0       # possible binary frames refused: the frame after them was not
    resyncs: int = 0           # synch tokens asked for after the first
    bytes_skipped: int = 0


class AhrsDecoder:
    """Stream decoder for `#oscb` (binary, after a synch token) or `#osct` (text)."""

    def __init__(self, binary: bool = True):
        self.binary = binary
        self.stats = AhrsStats()
        self._buf = bytearray()
        self._base = 0
        self._token: bytes | None = None
        self._synced = False
        self._text_frames = 0
        self._text_frame: dict[bytes, tuple] = {}

    @property
    def synced(self) -> bool:
        return self._synced

    @property
    def needs_sync(self) -> bool:
        """Binary frames carry no marks: after an impossible frame, ask for a new token."""
        return self.binary and not self._synced and self._token is None

    def reset(self) -> None:
        self._buf.clear()
        self._base = 0
        self._token = None
        self._synced = False
        self._text_frame.clear()

    def expect_sync(self, token: bytes) -> None:
        self._token = token
        self._synced = False

    @property
    def waiting(self) -> bool:
        """Binary bytes wait for more; silence will judge them."""
        return self.binary and self._synced and len(self._buf) > 0

    def feed(self, data: bytes) -> list[tuple[float, int, Frame]]:
        self._buf += data
        return self._feed_binary() if self.binary else self._feed_text()

    def silence(self) -> list[tuple[float, int, Frame]]:
        """The line has been quiet for a frame time. The firmware writes each frame in one
        go and pauses only between frames, so whole frames up to the pause ended there and
        are accepted, and part of a frame means bytes were lost or added: the frames are off
        their boundaries, and the synchronisation is dropped."""
        if not self.waiting:
            return []
        if len(self._buf) % SENSORS.size == 0:
            return self._feed_binary(silent=True)
        self.stats.unconfirmed += len(self._buf) // SENSORS.size
        self.stats.bad_frames += 1
        self._lose_sync()
        return []

    def _consume(self, n: int) -> None:
        del self._buf[:n]
        self._base += n

    def _find_token(self) -> bool:
        if self._token is None:                  # lost: drop everything until asked
            self.stats.bytes_skipped += len(self._buf)
            self._consume(len(self._buf))
            return False
        reply = sync_reply(self._token)
        at = self._buf.find(reply)
        if at < 0:
            drop = max(0, len(self._buf) - len(reply) + 1)
            self.stats.bytes_skipped += drop
            self._consume(drop)
            return False
        self.stats.bytes_skipped += at
        self._consume(at + len(reply))
        self._synced = True
        return True

    def _feed_binary(self, silent: bool = False) -> list[tuple[float, int, Frame]]:
        """Whole frames are held until the line pauses after them (`silent`); more than
        MAX_HELD of them, on a link that hands bytes over without pauses, are let go while
        the frames after them are possible too. An impossible frame drops the
        synchronisation, with the frames held before it."""
        if not self._synced and not self._find_token():
            return []
        size = SENSORS.size
        whole = len(self._buf) // size
        for k in range(whole):
            if not _possible(SENSORS.unpack_from(self._buf, k * size)):
                self.stats.unconfirmed += k
                self.stats.bad_frames += 1
                self._lose_sync()
                return []
        out = []
        for _ in range(whole if silent else max(0, whole - MAX_HELD)):
            values = SENSORS.unpack_from(self._buf, 0)
            offset = self._base
            self._consume(size)
            self.stats.frames += 1
            out.append((offset / size, offset, to_board(values[0:3], values[3:6], values[6:9])))
        return out

    def _lose_sync(self) -> None:
        """Binary frames carry no marks: drop everything until a new token is asked for."""
        self._synced = False
        self._token = None
        self.stats.bytes_skipped += len(self._buf)
        self._consume(len(self._buf))

    def _feed_text(self) -> list[tuple[float, int, Frame]]:
        out = []
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                if len(self._buf) > 256:        # no line end in sight: garbage
                    self.stats.bytes_skipped += len(self._buf)
                    self._consume(len(self._buf))
                break
            offset = self._base
            line = bytes(self._buf[:nl]).strip()
            self._consume(nl + 1)
            if self._token is not None and line == sync_reply(self._token).strip():
                self._synced = True
                continue
            head, _, values = line.partition(b"=")
            if head in (b"#A-C", b"#M-C", b"#G-C"):
                try:
                    xyz = tuple(float(v) for v in values.split(b","))
                except ValueError:
                    xyz = ()
                if len(xyz) == 3:
                    if head == b"#A-C":
                        self._text_frames += 1
                        self._text_frame = {}
                    self._text_frame[head] = xyz
                    if head == b"#G-C" and len(self._text_frame) == 3:
                        f = self._text_frame
                        out.append((float(self._text_frames), offset,
                                    to_board(f[b"#A-C"], f[b"#M-C"], f[b"#G-C"])))
                        self.stats.frames += 1
                        self._text_frame = {}
                    continue
                self.stats.bad_frames += 1
            self.stats.bytes_skipped += nl + 1
        return out


def _possible(values) -> bool:
    return all(-lim <= v <= lim for v, lim in zip(values, _LIMITS))       # False for nan


class SyncError(serial.SerialException):
    """The board never answered a synch request: wrong firmware, baud rate or port."""


class RazorAhrs(SerialImu):
    """A Razor running the stock Razor AHRS firmware, read as calibrated sensor values.

        >>> with RazorAhrs("/dev/ttyUSB0") as imu:
        ...     imu.read(timeout=2).frame.accel_g
    """

    firmware = "razor-ahrs"
    BAUDRATE = BAUDRATE
    RATE_HZ = RATE_HZ
    FRAME_BYTES = SENSORS.size

    def __init__(self, url: str, baudrate: int | None = None, *, output: str = "binary",
                 sync_timeout: float = 1.5, sync_attempts: int = 3, **kwargs):
        if output not in ("binary", "text"):
            raise ValueError("output must be 'binary' or 'text'")
        super().__init__(url, baudrate, **kwargs)
        self.decoder = AhrsDecoder(binary=output == "binary")
        self.sync_timeout = sync_timeout
        self.sync_attempts = sync_attempts
        self._tokens = itertools.cycle(b"%02d" % i for i in range(100))
        self._syncs = 0

    @property
    def stats(self) -> AhrsStats:
        return self.decoder.stats

    def _start_stream(self) -> None:
        self.decoder.reset()
        self.synchronise()

    def synchronise(self) -> None:
        """Stop the stream, choose the output mode, restart it and wait for the token.
        Retries because a freshly reset board spends its first second in the bootloader."""
        mode = CALIBRATED_BINARY if self.decoder.binary else CALIBRATED_TEXT
        for _ in range(self.sync_attempts):
            token = next(self._tokens)
            self.link.write(STREAM_OFF)
            self.decoder.expect_sync(token)
            self.link.write(ERRORS_OFF + mode + STREAM_ON + sync_request(token))
            deadline = clock.monotonic() + self.sync_timeout
            while clock.monotonic() < deadline:
                data, t_host = self.link.read(self.timeout)
                if data:
                    self._ingest(data, t_host)
                if self.decoder.synced:
                    if self._syncs:
                        self.decoder.stats.resyncs += 1
                    self._syncs += 1
                    return
        raise SyncError(f"{self.url}: no #SYNCH reply from the Razor AHRS firmware "
                        f"after {self.sync_attempts} tries")

    def read(self, timeout: float | None = None):
        if self.decoder.needs_sync:
            self.clock.reset()
            self.synchronise()
        return super().read(timeout)

    def _decode(self, data: bytes) -> list[tuple[float, int, Frame, int]]:
        return self._ends(self.decoder.feed(data))

    def _awaiting_silence(self) -> bool:
        return self.decoder.waiting

    def _decode_silence(self) -> list[tuple[float, int, Frame, int]]:
        return self._ends(self.decoder.silence())

    def _ends(self, frames) -> list[tuple[float, int, Frame, int]]:
        """Where each frame ends: a binary frame is 36 bytes; a text frame ended in the
        chunk just read (it needs no look-ahead)."""
        if self.decoder.binary:
            return [(slot, offset, frame, offset + SENSORS.size) for slot, offset, frame in frames]
        return [(slot, offset, frame, self._received) for slot, offset, frame in frames]
