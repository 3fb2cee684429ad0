"""The Razor board on the car as the twins see it: truth in, what the sensors and the
firmware make of it out (docs/sensors.md#imu-sensor-models, the default calibration's figures
as defaults).

    accel  LSB = gain * f[g] + offset + noise (ADXL345, integer LSB);
           the firmware sends (LSB - eeprom_offset) / eeprom_gain   (docs/sensors.md#accelerometer-model)
    gyro   deg/s = w + bias + noise, in ITG-3200 steps of 1/14.375  (docs/sensors.md#gyro-model)
    mag    counts = C R h_e + offset + noise (HMC5843, integer counts) (docs/sensors.md#magnetometer-model)
           with the Lisbon field, C and offset from the default calibration (z untouched)

Noise levels are those of the car's parked recordings (traction motor off).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from viena.common.rotation import euler_from_quat
from viena.services.imu.driver.razor_ahrs import GYRO_LSB_PER_DPS
from viena.services.imu.model.calibration import (
    HMC5843_TESLA_PER_COUNT,
    STANDARD_GRAVITY,
    TABLE_5_3_GAIN_LSB_PER_G,
    TABLE_5_3_OFFSET_LSB,
    seed_calibration,
)
from viena.services.imu.model.mount import Mount

LISBON_FIELD_ENU_NT = (-1121.5, 26479.8, -34884.7)


def _seed_mag():
    seed = seed_calibration("viena")
    return seed.mag_offset, tuple(map(tuple, np.linalg.inv(np.array(seed.mag_c_inv)).tolist()))


_SEED_MAG_OFFSET, _SEED_MAG_C = _seed_mag()


def _rint(x: float) -> float:
    """np.rint of a Python float: to the nearest integer, halves to even, a zero keeping
    the sign of x (round() alone makes -0.3 into 0, not -0.0)."""
    if not math.isfinite(x):
        return x
    return math.copysign(float(round(x)), x)


class Measurement(NamedTuple):
    accel_lsb: tuple        # what the ADXL345 registers hold
    accel_g: tuple          # after the firmware's EEPROM calibration
    gyro_dps: tuple         # after the firmware's boot-time bias removal
    mag_counts: tuple       # HMC5843 registers
    euler_deg: tuple        # yaw, pitch, roll of the truth (the firmware's own are worse)


@dataclass(frozen=True)
class RazorBoard:
    """Make variants with dataclasses.replace(board, ...) or keyword arguments."""

    board_id: int = 1
    accel_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    accel_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    eeprom_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    eeprom_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    accel_noise_lsb: tuple = (1.45, 1.45, 2.0)        # ~0.0055, 0.0055, 0.008 g
    gyro_bias_dps: tuple = (0.01, 0.02, -0.01)        # what the boot average leaves
    gyro_noise_dps: tuple = (0.032, 0.037, 0.034)
    mag_offset_counts: tuple = _SEED_MAG_OFFSET       # hard iron, the default's, in counts
    mag_c: tuple = _SEED_MAG_C                        # soft iron: the inverse of the default C^-1
    mag_noise_counts: tuple = (3.4, 3.3, 5.0)
    tesla_per_count: float = HMC5843_TESLA_PER_COUNT
    field_enu_nT: tuple = LISBON_FIELD_ENU_NT
    #: how the board sits in the car (model/mount.py): board = R^T body
    mount_zyx_deg: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("accel_gain_lsb_per_g", "accel_offset_lsb", "eeprom_gain_lsb_per_g",
                     "eeprom_offset_lsb", "accel_noise_lsb", "gyro_bias_dps", "gyro_noise_dps",
                     "mag_offset_counts", "mag_c", "mag_noise_counts", "field_enu_nT"):
            object.__setattr__(self, "_" + name, np.array(getattr(self, name), float))
        object.__setattr__(self, "_to_board", Mount(tuple(self.mount_zyx_deg)).matrix.T)
        # the per-axis figures, axis by axis, as Python floats (for measure)
        object.__setattr__(self, "_accel_axes", tuple(zip(*(
            getattr(self, "_" + name).tolist() for name in (
                "accel_gain_lsb_per_g", "accel_offset_lsb", "accel_noise_lsb",
                "eeprom_offset_lsb", "eeprom_gain_lsb_per_g")))))
        object.__setattr__(self, "_gyro_axes", tuple(zip(
            self._gyro_bias_dps.tolist(), self._gyro_noise_dps.tolist())))
        object.__setattr__(self, "_mag_axes", tuple(zip(
            self._mag_offset_counts.tolist(), self._mag_noise_counts.tolist())))

    def measure(self, truth, rng: np.random.Generator) -> Measurement:
        """One sample of the three sensors (the noise drawn accel, gyro, mag, 3 each).

        The matrix products are numpy's; the per-axis arithmetic after them is written in
        Python floats, the same operations in the same order (the same bits), because on
        3-vectors numpy's per-call cost is several times the arithmetic's, every sample."""
        to_board = self._to_board
        f_g = (to_board @ np.asarray(truth.specific_force_body_mps2, float) / STANDARD_GRAVITY).tolist()
        noise = rng.standard_normal(3).tolist()
        lsb = [min(max(_rint(gain * f + offset + sigma * z), -4096.0), 4095.0)  # 13 bits at +-16 g
               for (gain, offset, sigma, _, _), f, z in zip(self._accel_axes, f_g, noise)]
        accel_g = [(v - eeprom_offset) / eeprom_gain
                   for (_, _, _, eeprom_offset, eeprom_gain), v in zip(self._accel_axes, lsb)]
        w_body = (to_board @ np.asarray(truth.gyro_body_radps, float)).tolist()
        noise = rng.standard_normal(3).tolist()
        w = [_rint((math.degrees(v) + bias + sigma * z) * GYRO_LSB_PER_DPS) / GYRO_LSB_PER_DPS
             for (bias, sigma), v, z in zip(self._gyro_axes, w_body, noise)]
        h = to_board @ np.asarray(truth.mag_body_T(self._field_enu_nT), float) / self.tesla_per_count
        soft = (self._mag_c @ h).tolist()
        noise = rng.standard_normal(3).tolist()
        m = [min(max(_rint(v + offset + sigma * z), -2048.0), 2047.0)
             for (offset, sigma), v, z in zip(self._mag_axes, soft, noise)]
        yaw, pitch, roll = euler_from_quat(truth.quat)
        return Measurement(tuple(lsb), tuple(accel_g), tuple(w), tuple(m),
                           (math.degrees(yaw), math.degrees(pitch), math.degrees(roll)))
