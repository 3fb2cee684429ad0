"""Framing the stock Razor AHRS firmware's binary output (issue 12). Its 36-byte frames carry
neither sync nor checksum, so a lost or extra byte shifts every frame after it; when the
shift is a whole number of floats, the shifted frames hold real values in the wrong fields
and look possible. The firmware writes each frame in one go and then pauses, so the line's
pause is the frame boundary the bytes lack: a pause with part of a frame buffered means the
frames are off their boundaries, and the decoder drops the synchronisation (the driver asks
for a new token) instead of publishing them.
"""
from __future__ import annotations

import itertools

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from viena.services.imu.driver import AhrsDecoder
from viena.services.imu.driver.razor_ahrs import SENSORS, from_board, sync_reply
from viena.services.imu.simulator.line import damage, real_shaped_ahrs_frames

#: flips are left out: with no checksum, a flipped bit that leaves a possible value cannot
#: be seen by any framing
SHIFTS = ("truncate", "delete", "insert")


def as_sent(frame) -> bytes:
    """A decoded frame back in the firmware's bytes."""
    acc, mag, gyr = from_board(frame.accel_g, frame.gyro_dps, frame.mag_counts)
    return SENSORS.pack(*acc, *mag, *gyr)


def decode(units, pauses: bool) -> tuple[list[bytes], AhrsDecoder]:
    """Feed the units, with the firmware's pause after each if `pauses`; whenever the decoder
    loses the synchronisation, answer the token request the driver would send."""
    decoder = AhrsDecoder(binary=True)
    tokens = (b"%02d" % (k % 100) for k in itertools.count())
    out = []
    for unit in [b""] + list(units):
        if decoder.needs_sync or not decoder.synced:
            token = next(tokens)
            decoder.expect_sync(token)
            decoder.feed(sync_reply(token))
        out += decoder.feed(unit)
        if pauses:
            out += decoder.silence()
    return [as_sent(f) for _, _, f in out], decoder


@given(rate=st.floats(0.02, 0.4), n=st.integers(2500, 2800), seed=st.integers(0, 2**32 - 1))
@settings(max_examples=20, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
def test_with_the_firmwares_pauses_no_shifted_frame_is_published(rate, n, seed):
    rng = np.random.default_rng(seed)
    pool = real_shaped_ahrs_frames()
    start = int(rng.integers(len(pool)))
    frames = [pool[(start + k) % len(pool)] for k in range(n)]
    s = damage(frames, rate, rng, pool, kinds=SHIFTS)
    out, decoder = decode(s.units, pauses=True)
    sent = set(frames)
    assert [f for f in out if f not in sent] == []
    whole = [u for u, f in zip(s.units, frames) if u == f]
    assert len(out) == len(whole)                   # and every whole frame came through
    assert decoder.stats.bad_frames >= 1


def test_a_frame_shifted_by_one_float_looks_possible_but_the_pause_gives_it_away():
    pool = real_shaped_ahrs_frames()
    a, b, c = pool[100:103]
    shifted = a[:-4]                          # the last float lost: b and c move by 4 bytes
    window = shifted + b[:4]
    assert all(-5e4 < v < 5e4 for v in SENSORS.unpack(window))     # possible values
    out, decoder = decode([shifted, b, c], pauses=True)
    assert out == [b, c] and decoder.stats.bad_frames == 1


def test_back_to_back_a_frame_is_published_only_when_the_next_one_is_possible_too():
    pool = real_shaped_ahrs_frames()
    a, b = pool[200:202]
    out, decoder = decode([a + b"\xff" * 36 + b], pauses=False)
    assert out == [] and decoder.stats.unconfirmed == 1
    out, _ = decode([a + b], pauses=True)
    assert out == [a, b]
