"""A Razor unit's calibration: what turns firmware frames into SI values in the body frame.

The models are those of docs/sensors.md#imu-sensor-models, applied to what the firmware
sends (board axes, which on the car are the body axes: x right, y forward, z up):

- accelerometer: the firmware already divides by the gains and offsets in its EEPROM,
  frame[g] = (LSB - eeprom_offset) / eeprom_gain, so the host undoes that and applies its
  own six-position line LSB = gain * a[g] + offset. The default calibration is both
  (docs/sensors.md#default-calibration).
- gyro: rate = frame - bias (the firmware removes a boot-time bias; the host the rest).
- magnetometer: H_c = C^-1 (H_s - offset) (docs/sensors.md#imu-calibration), then
  tesla = H_c * tesla_per_unit. The default's offset is given in nT; in HMC5843 counts at
  1300 counts/gauss.

Calibrations live in a TOML file, one table per unit, written by `viena calibrate imu`
(see `viena.services.imu.calibration_cli`). A unit that has none gets the default
calibration ("the seed's values", docs/README.md#glossary), and the log says so.
"""
from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from viena.common.errors import ConfigError
from viena.services.imu.model.firmware_units import ACCEL_PER_G, DEFAULT_MAGN_SCALE
from viena.services.imu.model.fitting import AccelFit, GyroBiasFit, MagFit, ellipse_c_inv
from viena.services.imu.model.mount import Mount

MAX_TIME_OFFSET_S = 5.0
STANDARD_GRAVITY = 9.80665                     # m/s^2 per g
#: HMC5843 at the gain its i2cdevlib driver sets (1.0 Ga range): 1300 counts per gauss
HMC5843_TESLA_PER_COUNT = 1e-4 / 1300
FIRMWARES = ("viena", "razor-ahrs")

#: the default accelerometer calibration (docs/sensors.md#default-calibration; the names keep the
#: guide's table numbers), per axis x, y, z: LSB = gain * a[g] + offset
TABLE_5_3_GAIN_LSB_PER_G = (266.04, 266.27, 253.66)
TABLE_5_3_OFFSET_LSB = (13.83, -3.18, -3.47)
#: the default magnetometer calibration ("Razor 1", docs/sensors.md#default-calibration): hard-iron
#: offset in nT (x, y), ellipse angle and axis ratio
TABLE_5_4_OFFSET_NT = (-25828.0, -21703.0)
TABLE_5_4_ALPHA_DEG = 107.5238
TABLE_5_4_AXIS_RATIO = 0.9567
NAN = float("nan")
#: the car's Razor's noise (docs/sensors.md#imu-noise-figures): `viena calibrate imu noise nocurrent
#: speed_0hz`, its parked recordings with the traction motor off (77 s, values as its logger wrote
#: them, in 0.01 steps). Too short for a bias-instability floor: that is bounded, not measured.
CAR_RAZOR_NOISE = {
    "recordings": ["razor_parked_nocurrent", "razor_parked_speed_0hz"], "seconds": 77.2, "rate_hz": 82.4,
    "gyro": {"unit": "deg/s", "quantization": [NAN, NAN, NAN], "random_walk": [0.004844, 0.006489, 0.005147],
             "bias_instability": [NAN, NAN, NAN], "rate_random_walk": [NAN, NAN, NAN],
             "bias_instability_at_most": [0.002663, 0.006333, 0.003929], "resolution": 0.01,
             "bias_after_boot_rms": [0.00539, 0.005426, 0.003649]},
    "accel": {"unit": "g", "quantization": [NAN, NAN, NAN], "random_walk": [0.000659, 0.0006692, 0.0009815],
              "bias_instability": [NAN, NAN, NAN], "rate_random_walk": [NAN, NAN, NAN],
              "bias_instability_at_most": [0.0005136, 0.0005343, 0.0006221], "resolution": 0.01},
}

def _vec(v) -> tuple:
    return tuple(float(x) for x in v)


def _mat(m) -> tuple:
    return tuple(tuple(float(x) for x in row) for row in m)


@dataclass(frozen=True)
class ImuCalibration:
    firmware: str = "viena"
    accel_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    accel_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    eeprom_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    eeprom_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    gyro_bias_dps: tuple = (0.0, 0.0, 0.0)
    mag_offset: tuple = (0.0, 0.0, 0.0)          # in the firmware's magnetometer units
    mag_c_inv: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    tesla_per_mag_unit: float = HMC5843_TESLA_PER_COUNT
    mag_method: str = "seed"
    #: board to body rotation (model/mount.py): published samples are in the body frame
    mount_zyx_deg: tuple = (0.0, 0.0, 0.0)
    #: added to the unit's timestamps: t_true = t_stamped + time_offset_s (model/time_offset.py)
    time_offset_s: float = 0.0
    source: str = field(default="seed", compare=False)    # "seed", or the file it came from
    updated: str = field(default="", compare=False)
    info: dict = field(default_factory=dict, compare=False)   # fit reports, kept in the file
    #: Allan noise figures (`viena calibrate imu noise`, docs/sensors.md#imu-noise-figures): not
    #: used to calibrate samples; for whoever models the unit's errors (its twin, a filter)
    noise: dict = field(default_factory=dict, compare=False)

    # -- updating from fits -----------------------------------------------------------------
    def with_accel(self, fit: AccelFit) -> ImuCalibration:
        return dataclasses.replace(self, accel_gain_lsb_per_g=_vec(fit.gain_lsb_per_g),
                                   accel_offset_lsb=_vec(fit.offset_lsb),
                                   info={**self.info, "accel": {
                                       "rms_residual_g": list(fit.rms_residual_g),
                                       "samples": dict(fit.samples)}})

    def with_gyro(self, fit: GyroBiasFit) -> ImuCalibration:
        return dataclasses.replace(self, gyro_bias_dps=_vec(fit.bias_dps),
                                   info={**self.info, "gyro": {"std_dps": list(fit.std_dps),
                                                                "samples": fit.samples}})

    def with_mag(self, fit: MagFit) -> ImuCalibration:
        info = {"rms_residual": fit.rms_residual, "radius": fit.radius}
        info.update({k: v for k, v in fit.info.items() if k != "r_cal"})
        return dataclasses.replace(self, mag_offset=_vec(fit.offset), mag_c_inv=_mat(fit.c_inv),
                                   mag_method=fit.method, info={**self.info, "mag": info})

    def with_mount(self, mount: Mount, report: dict) -> ImuCalibration:
        return dataclasses.replace(self, mount_zyx_deg=tuple(mount.zyx_deg),
                                   info={**self.info, "mount": report})

    def with_noise(self, table: dict) -> ImuCalibration:
        return dataclasses.replace(self, noise=validate_noise(table, "noise"))

    def with_time_offset(self, offset_s: float, report: dict) -> ImuCalibration:
        return dataclasses.replace(self, time_offset_s=float(offset_s),
                                   info={**self.info, "timing": report})

    @property
    def mount(self) -> Mount:
        return Mount(tuple(self.mount_zyx_deg))

    def board_frame(self) -> ImuCalibration:
        """The same calibration without the mount: values in the board's own axes."""
        return dataclasses.replace(self, mount_zyx_deg=(0.0, 0.0, 0.0))

    # -- frames to LSB and back (what the accelerometer fit works on) ---------------------------
    def accel_lsb(self, accel_g: np.ndarray) -> np.ndarray:
        """Undo the firmware's EEPROM calibration: frame g -> chip LSB."""
        return np.asarray(accel_g, float) * self.eeprom_gain_lsb_per_g + self.eeprom_offset_lsb

    def validate(self, where: str = "calibration") -> ImuCalibration:
        if self.firmware not in FIRMWARES:
            raise ConfigError(f"{where}: firmware must be one of {', '.join(FIRMWARES)}")
        for name in ("accel_gain_lsb_per_g", "eeprom_gain_lsb_per_g"):
            if not all(math.isfinite(g) and g > 0 for g in getattr(self, name)):
                raise ConfigError(f"{where}: {name} must be three positive numbers")
        for name in ("accel_offset_lsb", "eeprom_offset_lsb", "gyro_bias_dps", "mag_offset"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ConfigError(f"{where}: {name} must be three finite numbers")
        m = np.array(self.mag_c_inv, float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-6:
            raise ConfigError(f"{where}: mag c_inv must be an invertible 3x3 matrix")
        if not (math.isfinite(self.tesla_per_mag_unit) and self.tesla_per_mag_unit > 0):
            raise ConfigError(f"{where}: mag tesla_per_unit must be positive")
        if len(self.mount_zyx_deg) != 3 or not all(math.isfinite(a) and abs(a) <= 360 for a in self.mount_zyx_deg):
            raise ConfigError(f"{where}: mount zyx_deg must be three angles in degrees")
        if not (math.isfinite(self.time_offset_s) and abs(self.time_offset_s) <= MAX_TIME_OFFSET_S):
            raise ConfigError(f"{where}: timing offset_s must be within +-{MAX_TIME_OFFSET_S} s")
        return self


def seed_calibration(firmware: str = "viena") -> ImuCalibration:
    """The default calibration (docs/sensors.md#default-calibration) in the units each firmware sends."""
    c_inv = _mat(ellipse_c_inv(math.radians(TABLE_5_4_ALPHA_DEG), TABLE_5_4_AXIS_RATIO))
    offset_counts = tuple(nt * 1e-9 / HMC5843_TESLA_PER_COUNT for nt in TABLE_5_4_OFFSET_NT) + (0.0,)
    noise = copy.deepcopy(CAR_RAZOR_NOISE)
    if firmware == "viena":
        return ImuCalibration(firmware, mag_offset=offset_counts, mag_c_inv=c_inv, noise=noise)
    if firmware == "razor-ahrs":
        # The stock firmware sends its own calibrated values: accel in 1/256 g (the driver
        # divides), magnetometer in counts * 100/600 with its default MAGN limits.
        nominal = (ACCEL_PER_G,) * 3
        return ImuCalibration(firmware, nominal, (0.0,) * 3, nominal, (0.0,) * 3,
                              mag_offset=tuple(c * DEFAULT_MAGN_SCALE for c in offset_counts),
                              mag_c_inv=c_inv,
                              tesla_per_mag_unit=HMC5843_TESLA_PER_COUNT / DEFAULT_MAGN_SCALE, noise=noise)
    raise ValueError(f"unknown firmware {firmware!r}")


# -- applying it, fast: one affine map per sensor ---------------------------------------------
class SampleCalibrator:
    """Precomputes the per-sensor affine maps so one frame costs a few float operations."""

    def __init__(self, cal: ImuCalibration):
        self.calibration = cal
        g = STANDARD_GRAVITY
        eg, eo = cal.eeprom_gain_lsb_per_g, cal.eeprom_offset_lsb
        hg, ho = cal.accel_gain_lsb_per_g, cal.accel_offset_lsb
        rot = cal.mount.matrix
        # each sensor: body = R (scale * board + bias) = M board + c, with the mount R folded in
        a_scale = np.diag([g * eg[i] / hg[i] for i in range(3)])
        a_bias = np.array([g * (eo[i] - ho[i]) / hg[i] for i in range(3)])
        self._a_np, self._a_bias_np = rot @ a_scale, rot @ a_bias
        self._w_np = rot * (math.pi / 180.0)
        self._w_bias_np = -rot @ np.radians(np.array(cal.gyro_bias_dps, float))
        m = np.array(cal.mag_c_inv, float) * cal.tesla_per_mag_unit
        self._m_np, self._m_bias_np = rot @ m, -rot @ m @ np.array(cal.mag_offset, float)
        self._a, self._a_bias = self._a_np.tolist(), self._a_bias_np.tolist()
        self._w, self._w_bias = self._w_np.tolist(), self._w_bias_np.tolist()
        self._m, self._m_bias = self._m_np.tolist(), self._m_bias_np.tolist()
        self.time_offset_ns = int(round(cal.time_offset_s * 1e9))

    @staticmethod
    def _affine(m, b, v) -> list[float]:
        """m v + b for 3-vectors, in plain floats (a frame costs microseconds)."""
        (m0, m1, m2), x, y, z = m, v[0], v[1], v[2]
        return [m0[0] * x + m0[1] * y + m0[2] * z + b[0],
                m1[0] * x + m1[1] * y + m1[2] * z + b[1],
                m2[0] * x + m2[1] * y + m2[2] * z + b[2]]

    def accel(self, a) -> list[float]:
        return self._affine(self._a, self._a_bias, a)

    def gyro(self, w) -> list[float]:
        return self._affine(self._w, self._w_bias, w)

    def mag(self, h) -> list[float]:
        return self._affine(self._m, self._m_bias, h)

    def time_ns(self, t_stamped_ns: int) -> int:
        """The acquisition time on the reference clock (the unit's time offset applied)."""
        return t_stamped_ns + self.time_offset_ns

    # vectorised, for recordings
    def accel_array(self, a: np.ndarray) -> np.ndarray:
        return np.asarray(a, float) @ self._a_np.T + self._a_bias_np

    def gyro_array(self, w: np.ndarray) -> np.ndarray:
        return np.asarray(w, float) @ self._w_np.T + self._w_bias_np

    def mag_array(self, h: np.ndarray) -> np.ndarray:
        return np.asarray(h, float) @ self._m_np.T + self._m_bias_np


# -- the TOML file ------------------------------------------------------------------------------
def to_table(cal: ImuCalibration) -> dict:
    table = {
        "firmware": cal.firmware,
        "updated": cal.updated,
        "accel": {"gain_lsb_per_g": list(cal.accel_gain_lsb_per_g),
                  "offset_lsb": list(cal.accel_offset_lsb),
                  "eeprom_gain_lsb_per_g": list(cal.eeprom_gain_lsb_per_g),
                  "eeprom_offset_lsb": list(cal.eeprom_offset_lsb)},
        "gyro": {"bias_dps": list(cal.gyro_bias_dps)},
        "mag": {"method": cal.mag_method, "offset": list(cal.mag_offset),
                "c_inv": [list(r) for r in cal.mag_c_inv], "tesla_per_unit": cal.tesla_per_mag_unit},
        "mount": {"zyx_deg": list(cal.mount_zyx_deg)},
        "timing": {"offset_s": cal.time_offset_s},
    }
    if cal.noise:
        table["noise"] = cal.noise
    if cal.info:
        table["info"] = cal.info
    return table


#: the noise table's per-axis entries (docs/sensors.md#imu-noise-figures)
NOISE_SENSORS = ("gyro", "accel")
NOISE_TERMS = ("quantization", "random_walk", "bias_instability", "bias_instability_at_most",
               "rate_random_walk", "bias_after_boot_rms")


def validate_noise(table: dict, where: str) -> dict:
    """A noise table as stored: per sensor, each term three numbers >= 0, or nan where the
    recordings did not show it. Other keys (where the figures came from) are kept as they are."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: must be a table")
    for sensor in NOISE_SENSORS:
        sub = table.get(sensor, {})
        if not isinstance(sub, dict):
            raise ConfigError(f"{where}.{sensor}: must be a table")
        for term in NOISE_TERMS:
            v = sub.get(term)
            if v is None:
                continue
            if (not isinstance(v, list) or len(v) != 3
                    or not all(isinstance(x, (int, float)) and (math.isnan(x) or 0 <= x < math.inf) for x in v)):
                raise ConfigError(f"{where}.{sensor}.{term}: must be three numbers >= 0 (nan: not measured)")
    return table


def noise_figure(noise: dict, sensor: str, term: str) -> tuple | None:
    """One term's three values, None where the table has no such term or all are nan."""
    v = noise.get(sensor, {}).get(term)
    if v is None or all(math.isnan(x) for x in v):
        return None
    return tuple(float(x) for x in v)


def from_table(table: dict, where: str, source: str) -> ImuCalibration:
    """A unit's table; sensors or values it leaves out keep the default calibration."""
    try:
        firmware = table.get("firmware", "viena")
        base = seed_calibration(firmware) if firmware in FIRMWARES else ImuCalibration(firmware)
        accel, gyro, mag = table.get("accel", {}), table.get("gyro", {}), table.get("mag", {})
        mount, timing = table.get("mount", {}), table.get("timing", {})
        cal = ImuCalibration(
            firmware=firmware,
            accel_gain_lsb_per_g=_vec(accel.get("gain_lsb_per_g", base.accel_gain_lsb_per_g)),
            accel_offset_lsb=_vec(accel.get("offset_lsb", base.accel_offset_lsb)),
            eeprom_gain_lsb_per_g=_vec(accel.get("eeprom_gain_lsb_per_g", base.eeprom_gain_lsb_per_g)),
            eeprom_offset_lsb=_vec(accel.get("eeprom_offset_lsb", base.eeprom_offset_lsb)),
            gyro_bias_dps=_vec(gyro.get("bias_dps", base.gyro_bias_dps)),
            mag_offset=_vec(mag.get("offset", base.mag_offset)),
            mag_c_inv=_mat(mag.get("c_inv", base.mag_c_inv)),
            tesla_per_mag_unit=float(mag.get("tesla_per_unit", base.tesla_per_mag_unit)),
            mag_method=str(mag.get("method", base.mag_method)),
            mount_zyx_deg=_vec(mount.get("zyx_deg", base.mount_zyx_deg)),
            time_offset_s=float(timing.get("offset_s", base.time_offset_s)),
            source=source, updated=str(table.get("updated", "")),
            info=dict(table.get("info", {})),
            noise=validate_noise(table.get("noise", base.noise), f"{where} noise"))
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return cal.validate(where)
