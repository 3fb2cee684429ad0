"""The stock Razor AHRS firmware: its axes and units, its stream, its synch handshake,
driver against twin over socket://."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from viena.common.twin.serial_port import SerialEndpoint
from viena.services.imu.driver import AhrsDecoder, RazorAhrs, SyncError
from viena.services.imu.driver.razor_ahrs import from_board, sync_reply, to_board
from viena.services.imu.simulator import RazorAhrsTwin, RazorBoard
from viena.services.imu.simulator.scenarios import fixed_truth


def test_axis_and_unit_mapping_is_its_own_inverse():
    acc, mag, gyr = from_board((0.1, -0.2, 0.98), (1.0, -2.0, 3.0), (-250.0, 180.0, -350.0))
    f = to_board(acc, mag, gyr)
    assert np.allclose(f.accel_g, (0.1, -0.2, 0.98))
    assert np.allclose(f.gyro_dps, (1.0, -2.0, 3.0))
    assert np.allclose(f.mag_counts, (-250.0, 180.0, -350.0))


def test_the_firmware_frame_is_x_forward_of_the_connector_y_right_z_down():
    # board level (z up): the firmware's accel is the gravity vector, +256 on its Z (down)
    acc, mag, gyr = from_board((0.0, 0.0, 1.0), (0.0, 0.0, 10.0), (0.0, 0.0, -300.0))
    assert acc == (0.0, 0.0, 256.0)
    assert gyr[2] == pytest.approx(-10.0 * 14.375)      # yawing left is negative about Z down
    assert mag[2] == 300.0                               # field pointing down reads + on Z


def binary_frames(n, token=b"42"):
    vals = [from_board((0.0, 0.1 * k, 1.0), (0.0, 0.0, 1.0), (100.0, 0.0, -300.0)) for k in range(n)]
    return vals, b"".join(struct.pack("<9f", *a, *m, *g) for a, m, g in vals)


def test_binary_frames_count_only_after_the_synch_token():
    _, body = binary_frames(5)
    d = AhrsDecoder(binary=True)
    d.expect_sync(b"42")
    junk = b"#YPR=1.00,2.00,3.00\r\n" + body[:20]            # in flight before the mode change
    out = d.feed(junk + sync_reply(b"42") + body) + d.silence()     # the stream pauses after it
    assert [round(f.accel_g[1], 3) for _, _, f in out] == [0.0, 0.1, 0.2, 0.3, 0.4]
    assert d.stats.bytes_skipped == len(junk)


def test_an_impossible_binary_frame_drops_sync_until_a_new_token():
    _, body = binary_frames(3)
    d = AhrsDecoder(binary=True)
    d.expect_sync(b"01")
    # a frame, the firmware's pause, then an impossible frame and the rest
    out = d.feed(sync_reply(b"01") + body[:36]) + d.silence() + d.feed(b"\xff" * 36 + body[36:])
    assert len(out) == 1 and d.stats.bad_frames == 1 and d.needs_sync
    assert d.feed(body) == []                                  # ignored until re-synchronised
    d.expect_sync(b"02")
    assert len(d.feed(sync_reply(b"02") + body) + d.silence()) == 3


def test_text_frames_need_all_three_lines():
    d = AhrsDecoder(binary=False)
    text = (b"#A-C=0.00,0.00,256.00\r\n#M-C=1.00,2.00,3.00\r\n#G-C=0.00,0.00,14.38\r\n"
            b"#M-C=1.00,2.00,3.00\r\n#G-C=0.00,0.00,0.00\r\n"          # lost its #A line
            b"#A-C=x,y\r\n")
    out = d.feed(text)
    assert len(out) == 1
    f = out[0][2]
    assert f.accel_g == (0.0, 0.0, 1.0) and f.mag_counts == (-2.0, -1.0, -3.0)
    assert f.gyro_dps[2] == pytest.approx(-1.0, abs=1e-3)
    assert d.stats.bad_frames == 1


@pytest.mark.slow  # the twin boots in real time
@pytest.mark.parametrize("output", ["binary", "text"])
def test_driver_synchronises_with_the_twin_through_its_boot(output):
    board = RazorBoard(mag_noise_counts=(0, 0, 0), accel_noise_lsb=(0, 0, 0), gyro_noise_dps=(0, 0, 0))
    twin = RazorAhrsTwin(lambda: fixed_truth(gyro=(0, 0, 0.2)), board, boot_s=0.3)
    endpoint = SerialEndpoint(twin).start()
    try:
        with RazorAhrs(endpoint.url, output=output, sync_timeout=0.5) as imu:
            readings = [imu.read(timeout=2.0) for _ in range(10)]
    finally:
        endpoint.stop()
    assert all(r is not None for r in readings)
    assert [r.seq for r in readings] == list(range(10))
    assert twin.swallowed > 0            # the first request fell into the bootloader
    assert b"#o1" in twin.commands and (b"#oscb" if output == "binary" else b"#osct") in twin.commands
    f = readings[-1].frame
    assert f.board_id is None and f.euler_deg is None
    assert np.allclose(f.accel_g, (0, 0, 9.8006 / 9.80665), atol=0.01)
    assert f.gyro_dps[2] == pytest.approx(np.degrees(0.2), abs=0.1)


@pytest.mark.slow  # waits out the sync timeouts
def test_silence_is_a_sync_error():
    from viena.services.imu.simulator import RazorTwin  # the VIENA firmware never answers
    endpoint = SerialEndpoint(RazorTwin(lambda: fixed_truth(yaw=0.3, gyro=(0, 0, 0.1)), boot_s=0.0)).start()
    try:
        with pytest.raises(SyncError, match="no #SYNCH"):
            RazorAhrs(endpoint.url, sync_timeout=0.2, sync_attempts=2).open()
    finally:
        endpoint.stop()
