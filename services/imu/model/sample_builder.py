"""How a reading of the Razor becomes a viena.imu.sample/1 (common/samples/imu.py): the
unit's calibration applied, the magnetometer's glitches dropped, the firmware's values kept."""
from __future__ import annotations

from typing import TYPE_CHECKING

from viena.services.imu.model.calibration import SampleCalibrator
from viena.services.imu.model.glitch import MagGlitchFilter

if TYPE_CHECKING:  # the driver's frames, read here without loading the driver (and serial)
    from viena.services.imu.driver import Reading


class SampleBuilder:
    """Reading -> sample dict, for one unit."""

    def __init__(self, unit: str, firmware: str, calibrator: SampleCalibrator,
                 mag_filter: MagGlitchFilter | None = None):
        self.unit, self.firmware = unit, firmware
        self.calibrator = calibrator
        self.mag_filter = mag_filter or MagGlitchFilter()

    def build(self, reading: Reading) -> dict:
        f = reading.frame
        cal = self.calibrator
        mag = cal.mag(f.mag_counts)
        return {
            "t": cal.time_ns(reading.t_ns),
            "seq": reading.seq,
            "unit": self.unit,
            "firmware": self.firmware,
            "accel_mps2": cal.accel(f.accel_g),
            "gyro_radps": cal.gyro(f.gyro_dps),
            "mag_T": mag if self.mag_filter.accept(mag) else None,
            "raw": {"accel_g": list(f.accel_g), "gyro_dps": list(f.gyro_dps),
                    "mag_counts": list(f.mag_counts),
                    "euler_deg": None if f.euler_deg is None else list(f.euler_deg)},
            "board_id": f.board_id,
        }
