"""viena.imu.sample/1 on viena/<car>/imu/<unit>/sample: its schema, its reader and its monitor view.

Calibrated values in SI and the body frame (x right, y forward, z up), plus what the
firmware sent, unchanged, so the unit can be re-calibrated from any recording.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from viena.common.display import fmt_num, fmt_vec, norm
from viena.common.schema import F, Schema

SAMPLE = Schema("viena.imu.sample/1", {
    "t": F.time,                       # acquisition time, int ns UTC (estimated, see driver.timing)
    "seq": F.int,                      # host frame counter: gaps are lost frames
    "unit": F.str,
    "firmware": F.enum("viena", "razor-ahrs"),
    "accel_mps2": F.vec(3),            # specific force (at rest: +9.8 on z)
    "gyro_radps": F.vec(3),
    "mag_T": F.optional(F.vec(3)),     # None when the reading was a glitch (see glitch.py)
    "raw": F.struct({
        "accel_g": F.vec(3),           # as the firmware sent them, board axes
        "gyro_dps": F.vec(3),
        "mag_counts": F.vec(3),        # counts (VIENA firmware) or the stock firmware's units
        "euler_deg": F.optional(F.vec(3)),   # firmware's yaw, pitch, roll: not to be trusted
    }),
    "board_id": F.optional(F.int),     # EEPROM id (None: the stock firmware has none)
})


class ImuSample(NamedTuple):
    """An IMU sample as a consumer reads it (the estimator): the fields the README's
    "Estimator" section lists, which any source may publish, checked by SAMPLE's own
    checks. Made by `read_sample`. Vectors are lists of floats (the sample's own when
    they already were, not copied): the estimator reads them once per sample, in scalar code."""

    t: int
    unit: str
    accel_mps2: list[float]
    gyro_radps: list[float]
    mag_T: list[float] | None


#: the fields an ImuSample is read from; a source with one unit may leave out `unit`
_SAMPLE_FIELDS = SAMPLE.reader(*ImuSample._fields, defaults={"unit": "imu"})


def read_sample(sample) -> ImuSample:
    """The ImuSample in a decoded sample from any source; a FieldError (a SampleError)
    names the field that is missing or wrong."""
    return ImuSample._make(_SAMPLE_FIELDS(sample))


def monitor_view(sample: dict) -> dict[str, str]:
    """How the monitor shows an IMU sample (any map: what came on a sample key)."""
    mag_T = norm(sample.get("mag_T"), 3)
    return {
        "accel m/s²": fmt_vec(sample.get("accel_mps2")),
        "gyro °/s": fmt_vec(sample.get("gyro_radps"), 1, 180 / math.pi),
        "|mag| µT": "-" if mag_T is None else f"{mag_T * 1e6:.1f}",
        "seq": fmt_num(sample.get("seq")),
    }
