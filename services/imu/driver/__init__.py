"""Razor 9DOF IMU wire protocols: bytes in, typed frames out. No zenoh, no msgpack.

    >>> from viena.services.imu.driver import Razor
    >>> with Razor("socket://127.0.0.1:5000") as imu:
    ...     for reading in imu:
    ...         print(reading.seq, reading.frame.accel_g)
"""
from viena.services.imu.driver.crc import crc8_maxim
from viena.services.imu.driver.frames import FRAME_SIZE, DecoderStats, Frame, FrameDecoder, decode_frame, encode_frame
from viena.services.imu.driver.razor import Razor
from viena.services.imu.driver.razor_ahrs import AhrsDecoder, RazorAhrs, SyncError
from viena.services.imu.driver.serial_imu import Reading, SerialImu

DRIVERS = {Razor.firmware: Razor, RazorAhrs.firmware: RazorAhrs}

__all__ = ["crc8_maxim", "FRAME_SIZE", "DecoderStats", "Frame", "FrameDecoder", "decode_frame",
           "encode_frame", "Razor", "RazorAhrs", "AhrsDecoder", "SyncError", "Reading",
           "SerialImu", "DRIVERS"]
