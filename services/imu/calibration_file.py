"""The IMU calibration file: one TOML table per unit, read by the service, written by
`viena calibrate imu`. The calibration maths lives in model/calibration.py; this module
is its storage (file I/O), kept out of the model so the model stays pure."""
from __future__ import annotations

import dataclasses
import datetime as dt
import json
import math
import numbers
import os
import tempfile
import tomllib
from pathlib import Path

from viena.common.errors import ConfigError
from viena.services.imu.model.calibration import ImuCalibration, from_table, seed_calibration, to_table

DEFAULT_FILE = Path(os.environ.get("VIENA_CONFIG_DIR", "~/.config/viena")).expanduser() / "imu_calibration.toml"


def load_file(path: str | Path) -> dict:
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        return {}
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None


#: where the log sends a reader for "the seed's values" (the default calibration)
_DEFAULT_DOC = "the default calibration, docs/sensors.md#default-calibration"


def load_calibration(path: str | Path | None, unit: str, firmware: str = "viena") -> tuple[ImuCalibration, str]:
    """The unit's calibration and one line saying where it came from (for the log).
    A missing file or unit gives the default calibration (docs/sensors.md#default-calibration; the
    log calls it "the seed's values"); a broken one is a ConfigError."""
    if path is None:
        how = f"{unit}: no calibration file given: using the seed's values ({_DEFAULT_DOC})"
        return seed_calibration(firmware), how
    path = Path(path)
    tables = load_file(path)
    if unit not in tables:
        why = "no such file" if not path.exists() else f"no [{unit}] table"
        return seed_calibration(firmware), f"{unit}: {path}: {why}: using the seed's values ({_DEFAULT_DOC})"
    cal = from_table(tables[unit], f"{path} [{unit}]", str(path))
    if cal.firmware != firmware:
        raise ConfigError(f"{path} [{unit}]: calibrated for firmware {cal.firmware!r}, "
                          f"but the unit runs {firmware!r}")
    return cal, f"{unit}: calibration from {path} (updated {cal.updated or 'unknown'})"


def save_calibration(path: str | Path, unit: str, cal: ImuCalibration) -> ImuCalibration:
    """Write the unit's table, keeping the other units; atomic (temp file + rename)."""
    path = Path(path)
    cal = dataclasses.replace(cal.validate(f"{unit}"), source=str(path),
                              updated=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"))
    tables = load_file(path)
    tables[unit] = to_table(cal)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, dir=path.parent)
    with os.fdopen(fd, "w") as f:
        f.write(dumps(tables))
    os.replace(tmp, path)
    return cal


HEADER = """\
# viena IMU calibration: one table per unit, written by `viena calibrate imu`.
# accel (six-position fit, viena docs/sensors.md#accelerometer-six-position-fit), per axis x y z:
#   LSB = gain * a[g] + offset; the firmware sends
#   (LSB - eeprom_offset) / eeprom_gain, which the host undoes first.
# gyro: rate = frame - bias_dps.
# mag (viena docs/sensors.md#imu-calibration): H_c = c_inv (H_s - offset); tesla = tesla_per_unit * H_c.
# noise (viena docs/sensors.md#imu-noise-figures): Allan terms per axis in deg/s and g units;
#   nan: not shown by the recordings.
"""


def dumps(tables: dict, header: bool = True) -> str:
    """TOML for our calibration tables: vectors on one line, the model in a comment."""
    lines = [HEADER] if header else []

    def emit(prefix: str, table: dict) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        subs = {k: v for k, v in table.items() if isinstance(v, dict)}
        if scalars or not subs:
            lines.append(f"[{prefix}]")
            lines.extend(f"{_key(k)} = {_toml(v)}" for k, v in scalars.items())
            lines.append("")
        for k, v in subs.items():
            emit(f"{prefix}.{_key(k)}", v)

    for unit, table in tables.items():
        emit(_key(unit), table)
    return "\n".join(lines)


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):      # numpy's too: its repr is not TOML
        v = float(v)
        if math.isnan(v):
            return "nan"                 # TOML's own: a noise figure the recording did not show
        if not math.isfinite(v):
            raise ValueError(f"{v} cannot be stored")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml(x)}" for k, x in v.items()) + "}"
    raise ValueError(f"cannot store {v!r} in TOML")
