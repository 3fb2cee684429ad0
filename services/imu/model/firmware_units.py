"""The stock Razor AHRS firmware's output units: plain numbers, no I/O.

The driver (driver/razor_ahrs.py) decodes frames with them and the calibration model undoes
them; they live here so that the model reads them without loading the driver (and serial).
"""
ACCEL_PER_G = 256.0              # the firmware's GRAVITY constant
GYRO_LSB_PER_DPS = 14.375        # ITG-3200 sensitivity
#: magnetometer units per HMC5843 count with the firmware's default limits (MAGN_*_MIN/MAX
#: = -600/600 give MAGN_*_SCALE = 100 / 600)
DEFAULT_MAGN_SCALE = 100.0 / 600.0
