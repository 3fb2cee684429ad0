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
                     "mag_offset_counts", "mag_c", "mag_noise_counts"):
            object.__setattr__(self, "_" + name, np.array(getattr(self, name), float))
        object.__setattr__(self, "_to_board", Mount(tuple(self.mount_zyx_deg)).matrix.T)

    def measure(self, truth, rng: np.random.Generator) -> Measurement:
        to_board = self._to_board
        f_g = to_board @ np.asarray(truth.specific_force_body_mps2, float) / STANDARD_GRAVITY
        lsb = np.round(self._accel_gain_lsb_per_g * f_g + self._accel_offset_lsb
                       + self._accel_noise_lsb * rng.standard_normal(3))
        lsb = np.clip(lsb, -4096, 4095)                # 13 bits at +-16 g, full resolution
        accel_g = (lsb - self._eeprom_offset_lsb) / self._eeprom_gain_lsb_per_g
        w = (np.degrees(to_board @ np.asarray(truth.gyro_body_radps, float)) + self._gyro_bias_dps
             + self._gyro_noise_dps * rng.standard_normal(3))
        w = np.round(w * GYRO_LSB_PER_DPS) / GYRO_LSB_PER_DPS
        h = to_board @ np.asarray(truth.mag_body_T(self.field_enu_nT), float) / self.tesla_per_count
        m = np.round(self._mag_c @ h + self._mag_offset_counts
                     + self._mag_noise_counts * rng.standard_normal(3))
        m = np.clip(m, -2048, 2047)
        yaw, pitch, roll = euler_from_quat(truth.quat)
        return Measurement(tuple(lsb.tolist()), tuple(accel_g.tolist()), tuple(w.tolist()),
                           tuple(m.tolist()),
                           (math.degrees(yaw), math.degrees(pitch), math.degrees(roll)))
