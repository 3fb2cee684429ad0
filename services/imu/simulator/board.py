"""The Razor board on the car as the twins see it: truth in, what the sensors and the
firmware make of it out (docs/sensors.md#imu-sensor-models, docs/sensors.md#imu-error-model).

    accel  LSB = gain * (A f[g] + e_a) + offset + noise   (ADXL345, integer LSB);
           the firmware sends (LSB - eeprom_offset) / eeprom_gain   (docs/sensors.md#accelerometer-model)
    gyro   deg/s = G w + bias + e_g + lowpass(noise), in ITG-3200 steps of 1/14.375 (docs/sensors.md#gyro-model)
    mag    counts = C R h_e + offset + noise (HMC5843, integer counts) (docs/sensors.md#magnetometer-model)
           with the Lisbon field, C and offset from the default calibration (z untouched)

A, G (scale factor and misalignment) and e_a, e_g (turn-on bias, bias instability, rate
random walk, vibration) are one run's draws of `errors` (model/imu_errors.py). By default
they carry the car's own figures: the white noise and the bias-instability bound measured on
its parked recordings (the default calibration's noise table, `viena calibrate imu noise`),
vibration lines from its recordings with the traction motor running, and, where the
recordings cannot tell, the assumptions listed in docs/sensors.md#imu-error-model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from viena.services.imu.model.calibration import (
    HMC5843_TESLA_PER_COUNT,
    STANDARD_GRAVITY,
    TABLE_5_3_GAIN_LSB_PER_G,
    TABLE_5_3_OFFSET_LSB,
    noise_figure,
    seed_calibration,
)
from viena.services.imu.model.firmware_units import GYRO_LSB_PER_DPS
from viena.services.imu.model.imu_errors import (
    NO_ERRORS,
    RRW_CROSSING_S,
    ErrorState,
    ImuErrors,
    TriadErrors,
    VibrationLine,
)
from viena.services.imu.model.mount import Mount

LISBON_FIELD_ENU_NT = (-1121.5, 26479.8, -34884.7)
#: the firmware's loop (its frames' rate): white noise per sample is given at this rate
FIRMWARE_RATE_HZ = 82.5
#: the ITG-3200's digital low-pass as the VIENA firmware sets it (DLPF_CFG: 10 Hz)
ITG3200_LOWPASS_HZ = 10.0


def _seed_mag():
    seed = seed_calibration("viena")
    return seed.mag_offset, tuple(map(tuple, np.linalg.inv(np.array(seed.mag_c_inv)).tolist()))


_SEED_MAG_OFFSET, _SEED_MAG_C = _seed_mag()


# -- the car's figures ---------------------------------------------------------------------------------
def _car_noise():
    """White noise per sample from the default calibration's noise table (the car's parked
    recordings): the gyro's before its low-pass (which keeps N), the accelerometer's less
    what the car's logger's 0.01 g rounding and the chip's own LSB added to the recording."""
    noise = seed_calibration("viena").noise
    gyro_n = noise_figure(noise, "gyro", "random_walk")
    accel_n = noise_figure(noise, "accel", "random_walk")
    rounding = noise["accel"].get("resolution", 0.0)
    gyro_dps = tuple(round(n * math.sqrt(FIRMWARE_RATE_HZ), 4) for n in gyro_n)
    accel_lsb = tuple(round(gain * math.sqrt(max(n * n * FIRMWARE_RATE_HZ - (rounding ** 2 + 1.0 / gain ** 2) / 12.0,
                                                 0.0)), 3)
                      for n, gain in zip(accel_n, TABLE_5_3_GAIN_LSB_PER_G))
    return gyro_dps, accel_lsb


CAR_GYRO_NOISE_DPS, CAR_ACCEL_NOISE_LSB = _car_noise()


def _car_figure(sensor: str, *terms: str) -> tuple:
    """The first of `terms` the default calibration's noise table gives for `sensor` (the
    table ships with the code: one missing is a broken install, not a board without it)."""
    noise = seed_calibration("viena").noise
    for term in terms:
        value = noise_figure(noise, sensor, term)
        if value is not None:
            return value
    raise ValueError(f"the default calibration's noise table gives no {' or '.join(terms)} for the {sensor}")


def _triad(sensor: str, turn_on: tuple, scale: float, misalignment_rad: float, zero_at_start: bool) -> TriadErrors:
    """The car's bias instability: measured where the recordings show a floor, else their
    bound (the pessimistic end); rate random walk: measured, else the one that meets the
    floor at RRW_CROSSING_S (an assumption)."""
    b = _car_figure(sensor, "bias_instability", "bias_instability_at_most")
    k = noise_figure(seed_calibration("viena").noise, sensor, "rate_random_walk")
    if k is None:
        k = tuple(0.664 * x / math.sqrt(RRW_CROSSING_S / 3.0) for x in b)
    return TriadErrors(b, k, turn_on, scale, misalignment_rad, zero_at_start)


def _mg(*v: float) -> tuple:
    return tuple(x / 1000.0 for x in v)


#: The car's Razor (docs/sensors.md#imu-error-model). Gyro in deg/s, accelerometer in g.
CAR_RAZOR_ERRORS = ImuErrors(
    # turn-on: what the boot average left in the parked recordings (rms over them); the
    # wandering part starts at zero; scale 5 per mille, misalignment 3 mrad: assumptions
    gyro=_triad("gyro", _car_figure("gyro", "bias_after_boot_rms"), 0.005, 0.003, True),
    # turn-on against the six-position calibration: the ADXL345's offset drift (0.8, 0.8, 4.5
    # mg/degC typical) over a few degrees; scale 3 per mille, misalignment 3 mrad: assumptions
    accel=_triad("accel", _mg(3.0, 3.0, 8.0), 0.003, 0.003, False),
    lines=(
        # the traction motor running (parked recordings at 10 and 20 Hz): two narrow lines as the
        # board samples them, at 22.5 and 39.4 Hz whatever the motor's speed, and the motor's own
        # frequency (4 Hz per m/s: 10 Hz at 2.5 m/s, an assumption)
        VibrationLine(22.5, 0.2, (0.060, 0.016, 0.0069), _mg(1.62, 2.73, 5.91)),
        VibrationLine(39.4, 0.2, (0.0096, 0.0040, 0.0041), _mg(1.78, 3.92, 8.93)),
        VibrationLine(0.0, 0.2, (0.008, 0.0035, 0.003), _mg(1.45, 1.1, 1.25), hz_per_mps=4.0),
        # the road, at 10 m/s and growing with speed: body bounce and pitch, wheel hop (assumptions)
        VibrationLine(1.5, 0.5, (0.5, 0.3, 0.1), _mg(5.0, 3.0, 15.0), source="road"),
        VibrationLine(12.0, 3.0, (0.2, 0.2, 0.05), _mg(8.0, 8.0, 20.0), source="road"),
    ),
    engine_white_gyro_dps=(0.038, 0.012, 0.008),
    engine_white_accel_g=_mg(3.69, 4.80, 8.51),
)


def _rint(x: float) -> float:
    """np.rint of a Python float: to the nearest integer, halves to even, a zero keeping
    the sign of x (round() alone makes -0.3 into 0, not -0.0)."""
    if not math.isfinite(x):
        return x
    return math.copysign(float(round(x)), x)


def _register(x: float, lo: float, hi: float) -> float:
    """What a register of whole counts lo..hi holds for x: min(max(_rint(x), lo), hi), a nan
    staying nan (one call, not three: the board makes six of these per sample)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return math.copysign(float(round(x)), x) if x == x else x


class Measurement(NamedTuple):
    accel_lsb: tuple        # what the ADXL345 registers hold
    accel_g: tuple          # after the firmware's EEPROM calibration
    gyro_dps: tuple         # after the firmware's boot-time bias removal
    mag_counts: tuple       # HMC5843 registers
    euler_deg: tuple        # yaw, pitch, roll of the truth (the firmware's own are worse)


class _Chips(NamedTuple):
    """A board's figures as `measure` uses them, worked out once: the matrices, and the
    per-axis figures axis by axis, as Python floats."""

    to_board: np.ndarray        # how the board sits in the car: board = to_board body
    field_enu_T: np.ndarray     # the Earth's field, as Truth.mag_body_T scales it
    mag_rows: list              # body field [T] to HMC5843 counts before the offset: C to_board / tesla_per_count
    accel_axes: tuple           # (gain, offset, noise, eeprom offset, eeprom gain) per axis
    gyro_axes: tuple            # (bias, noise) per axis
    mag_axes: tuple             # (offset, noise) per axis

    @classmethod
    def of(cls, board: RazorBoard) -> _Chips:
        def axes(*figures: tuple) -> tuple:
            return tuple(zip(*(np.array(f, float).tolist() for f in figures)))
        to_board = Mount(tuple(board.mount_zyx_deg)).matrix.T
        return cls(to_board, np.array(board.field_enu_nT, float) * 1e-9,
                   (np.array(board.mag_c, float) @ to_board / board.tesla_per_count).tolist(),
                   axes(board.accel_gain_lsb_per_g, board.accel_offset_lsb, board.accel_noise_lsb,
                        board.eeprom_offset_lsb, board.eeprom_gain_lsb_per_g),
                   axes(board.gyro_bias_dps, board.gyro_noise_dps),
                   axes(board.mag_offset_counts, board.mag_noise_counts))


class _Run:
    """One run of the board (power-up to power-down): its error draws and filter states."""

    def __init__(self, board: RazorBoard, rng: np.random.Generator, t_s: float):
        self.errors: ErrorState = board.errors.start(rng, t_s)
        self.accel_to_board = self.errors.accel_matrix @ board._chips.to_board
        self.gyro_to_board = self.errors.gyro_matrix @ board._chips.to_board
        # the same, as rows of Python floats (for measure); the accelerometer's in g
        self.accel_rows = (self.accel_to_board / STANDARD_GRAVITY).tolist()
        self.gyro_rows = self.gyro_to_board.tolist()
        # the firmware subtracts a float boot average from whole ITG-3200 counts: its outputs
        # sit on the count grid shifted by that average's fraction
        self.grid_dps = float(rng.uniform(-0.5, 0.5)) / GYRO_LSB_PER_DPS if board.errors is not NO_ERRORS else 0.0
        self.lowpass = [0.0, 0.0, 0.0]
        self._alpha_dt, self._alpha = -1.0, 1.0
        self.cutoff_hz = board.gyro_lowpass_hz

    def alpha(self, dt: float) -> float:
        """The low-pass's gain for a step dt (the firmware's period when the truth stands still)."""
        if dt <= 0.0:
            dt = 1.0 / FIRMWARE_RATE_HZ
        if dt != self._alpha_dt:
            self._alpha_dt = dt
            self._alpha = 1.0 - math.exp(-2.0 * math.pi * self.cutoff_hz * dt) if self.cutoff_hz > 0 else 1.0
        return self._alpha


def _mat_vec(rows: list, v) -> list[float]:
    """rows v for a 3x3 matrix given as rows of Python floats and a 3-vector of them."""
    x, y, z = v
    return [r0 * x + r1 * y + r2 * z for r0, r1, r2 in rows]


@dataclass(frozen=True)
class RazorBoard:
    """Make variants with dataclasses.replace(board, ...) or keyword arguments; `errors=NO_ERRORS`
    leaves only the white noise and quantisation. One board is one board: it keeps its run's
    draws (the first `measure` makes them from the generator it is given), so give each twin
    its own."""

    board_id: int = 1
    accel_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    accel_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    eeprom_gain_lsb_per_g: tuple = TABLE_5_3_GAIN_LSB_PER_G
    eeprom_offset_lsb: tuple = TABLE_5_3_OFFSET_LSB
    accel_noise_lsb: tuple = CAR_ACCEL_NOISE_LSB      # white, per sample: ~0.0050, 0.0051, 0.0083 g
    gyro_bias_dps: tuple = (0.0, 0.0, 0.0)            # fixed; the turn-on bias is drawn (errors)
    gyro_noise_dps: tuple = CAR_GYRO_NOISE_DPS        # white, per sample, before the low-pass
    gyro_lowpass_hz: float = ITG3200_LOWPASS_HZ       # on the noise (0: none)
    mag_offset_counts: tuple = _SEED_MAG_OFFSET       # hard iron, the default's, in counts
    mag_c: tuple = _SEED_MAG_C                        # soft iron: the inverse of the default C^-1
    mag_noise_counts: tuple = (3.4, 3.3, 5.0)
    tesla_per_count: float = HMC5843_TESLA_PER_COUNT
    field_enu_nT: tuple = LISBON_FIELD_ENU_NT
    #: how the board sits in the car (model/mount.py): board = R^T body
    mount_zyx_deg: tuple = (0.0, 0.0, 0.0)
    errors: ImuErrors = CAR_RAZOR_ERRORS
    _chips: _Chips = field(init=False, repr=False, compare=False)      # made from the above
    _run: _Run | None = field(init=False, repr=False, compare=False)   # once the first measure starts it

    def __post_init__(self):
        object.__setattr__(self, "_chips", _Chips.of(self))
        object.__setattr__(self, "_run", None)

    def with_bias_step(self, gyro_dps=(0.0, 0.0, 0.0), accel_g=(0.0, 0.0, 0.0)) -> RazorBoard:
        """The same board after a bias step (a knock, a temperature jump): its run (error
        draws, filter states) goes on, with the gyro bias and the accelerometer offset moved."""
        stepped = replace(self, gyro_bias_dps=tuple(b + d for b, d in zip(self.gyro_bias_dps, gyro_dps)),
                          accel_offset_lsb=tuple(o + a * g for o, a, g in zip(
                              self.accel_offset_lsb, accel_g, self.eeprom_gain_lsb_per_g)))
        object.__setattr__(stepped, "_run", self._run)
        return stepped

    def run(self, rng: np.random.Generator, t_s: float = 0.0) -> _Run:
        """This board's run, started (its draws made) from `rng` the first time."""
        run = self._run
        if run is None:
            run = _Run(self, rng, t_s)
            object.__setattr__(self, "_run", run)
        return run

    def measure(self, truth, rng: np.random.Generator) -> Measurement:
        """One sample of the three sensors (the white noise drawn accel, gyro, mag, 3 each;
        the first sample also starts the run's errors from `rng`).

        Python floats throughout, the matrices as rows: on 3-vectors numpy's per-call cost is
        several times the arithmetic's, every sample."""
        run, chips = self._run or self.run(rng, truth.t_s), self._chips
        err = run.errors.step(truth.t_s, truth.speed_mps)
        noise = rng.standard_normal(9).tolist()          # as three draws of 3: accel, gyro, mag
        f_g = _mat_vec(run.accel_rows, truth.specific_force_body_mps2.tolist())
        lsb = [_register(gain * (f + e) + offset + sigma * z, -4096.0, 4095.0)        # 13 bits at +-16 g
               for (gain, offset, sigma, _, _), f, e, z in zip(chips.accel_axes, f_g, err[3:], noise)]
        accel_g = tuple([(v - eeprom_offset) / eeprom_gain
                         for (_, _, _, eeprom_offset, eeprom_gain), v in zip(chips.accel_axes, lsb)])
        w_body = _mat_vec(run.gyro_rows, truth.floats("gyro_body_radps"))
        alpha, grid = run.alpha(run.errors.dt), run.grid_dps
        low = run.lowpass = [x + alpha * (sigma * z - x)                # the chip's low-pass, on the noise
                             for x, (_, sigma), z in zip(run.lowpass, chips.gyro_axes, noise[3:6])]
        w = tuple([_rint((math.degrees(v) + bias + e + n + grid) * GYRO_LSB_PER_DPS) / GYRO_LSB_PER_DPS - grid
                   for (bias, _), v, e, n in zip(chips.gyro_axes, w_body, err, low)])
        soft = _mat_vec(chips.mag_rows, truth.body_of_enu(chips.field_enu_T).tolist())   # mag_body_T
        m = tuple([_register(v + offset + sigma * z, -2048.0, 2047.0)
                   for (offset, sigma), v, z in zip(chips.mag_axes, soft, noise[6:])])
        yaw, pitch, roll = truth.euler_rad
        return Measurement(tuple(lsb), accel_g, w, m, (math.degrees(yaw), math.degrees(pitch), math.degrees(roll)))
