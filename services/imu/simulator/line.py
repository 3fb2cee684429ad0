"""What a serial line and a USB adapter do to the Razor's frames: the damage the framing
must survive (tests and `viena bench imu`), on frames shaped like the car's own.

- `real_shaped_frames()`: every row of the car's parked recordings (data/imu) encoded as
  the firmware sends it (`real_shaped_ahrs_frames()`: as the stock firmware's `#oscb`);
- `damage(frames, rate, rng)`: each frame, with probability `rate`, cut short, missing a
  few bytes, with bytes inserted (random ones, or a piece of another real frame, sync and
  all), or with one bit flipped;
- `deliver(units, how, pause_p, rng)`: the chunks a host reads: every frame followed by the
  firmware's pause ("pauses": 1 ms of bytes then 11 ms of idle line at 82.5 Hz), or
  "bursts" of any size as a USB adapter hands them over, the line pausing after a burst
  with probability `pause_p`.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np

from viena.services.imu.driver.frames import encode_frame
from viena.services.imu.driver.razor_ahrs import SENSORS, from_board
from viena.services.imu.model.firmware_units import DEFAULT_MAGN_SCALE
from viena.services.imu.recordings import PARKED, load_parked

KINDS = ("truncate", "delete", "insert", "flip")
DELIVERIES = ("pauses", "bursts")
MAX_BURST = 700                 # bytes; the car's adapter handed over 6-7 frames at a time


@cache
def real_shaped_frames() -> tuple[bytes, ...]:
    """Every row of the car's parked recordings as the firmware's 52-byte frame."""
    out = []
    for name in PARKED:
        r = load_parked(name)
        out += [encode_frame(int(r.board_id[i]), r.accel_g[i], r.gyro_dps[i], r.mag_counts[i],
                             r.euler_deg[i]) for i in range(len(r))]
    return tuple(out)


@cache
def real_shaped_ahrs_frames() -> tuple[bytes, ...]:
    """The same rows as the stock firmware's calibrated binary frames (36 bytes)."""
    out = []
    for name in PARKED:
        r = load_parked(name)
        for i in range(len(r)):
            acc, mag, gyr = from_board(r.accel_g[i], r.gyro_dps[i], r.mag_counts[i] * DEFAULT_MAGN_SCALE)
            out.append(SENSORS.pack(*acc, *mag, *gyr))
    return tuple(out)


@dataclass
class DamagedStream:
    frames: list[bytes]         # what the firmware sent
    units: list[bytes]          # what each frame became on the line
    whole_at: dict[int, bytes]  # line position of every frame that is still whole
    damaged: int                # frames damaged

    @property
    def data(self) -> bytes:
        return b"".join(self.units)


def damage(frames: Sequence[bytes], rate: float, rng: np.random.Generator,
           pool: Sequence[bytes] | None = None, kinds: Sequence[str] = KINDS) -> DamagedStream:
    """Damage each frame with probability `rate` (one damage of a kind drawn from `kinds`);
    inserted pieces of frames come from `pool` (default: the frames themselves)."""
    pool = frames if pool is None else pool
    units, whole_at, damaged, pos = [], {}, 0, 0
    for frame in frames:
        unit = bytearray(frame)
        if rng.random() < rate:
            damaged += 1
            kind = kinds[int(rng.integers(len(kinds)))]
            size = len(frame)
            at = int(rng.integers(size))
            if kind == "truncate":
                del unit[max(1, at):]
            elif kind == "delete":
                del unit[at:at + int(rng.integers(1, 4))]
            elif kind == "insert":
                if rng.random() < 0.5:
                    junk = rng.integers(0, 256, int(rng.integers(1, 60)), dtype=np.uint8).tobytes()
                else:
                    other = pool[int(rng.integers(len(pool)))]
                    a = int(rng.integers(size))
                    junk = other[a:a + int(rng.integers(1, size))]
                unit[at:at] = junk
            else:
                unit[at] ^= 1 << int(rng.integers(8))
        whole = unit.find(frame)        # bytes inserted before a frame leave it whole
        if whole >= 0:
            whole_at[pos + whole] = frame
        units.append(bytes(unit))
        pos += len(unit)
    return DamagedStream(list(frames), units, whole_at, damaged)


def deliver(units: Sequence[bytes], how: str, pause_p: float,
            rng: np.random.Generator) -> list[tuple[bytes, bool]]:
    """The chunks the host reads, each with whether the line paused after it."""
    if how == "pauses":
        return [(u, True) for u in units]
    if how != "bursts":
        raise ValueError(f"delivery {how!r}: one of {DELIVERIES}")
    data = b"".join(units)
    chunks, k = [], 0
    while k < len(data):
        size = int(rng.integers(1, MAX_BURST))
        chunks.append((data[k:k + size], bool(rng.random() < pause_p)))
        k += size
    return chunks
