"""GNSS receivers' twins: NovAtel OEM4 (binary) and NMEA, from the simulated car's truth
or replaying the car's real 2016 drive, served to the unchanged drivers over socket://.

The sim builds them from its settings (``[sim.<name>]`` tables, see ``TWIN_SETTINGS``)::

    [sim.gnss0]
    kind = "novatel"                 # or "nmea"
    port = 0                         # TCP port (0 = any free one)
    lever_arm_m = [-0.4, 1.0, 1.5]   # antenna in the body frame (x right, y forward, z up)
    replay = ""                      # "" live from truth; "drive" = the 2016 drive; or a CSV
"""
from __future__ import annotations

import zlib
from pathlib import Path

from viena.common.config import merge_settings
from viena.common.errors import ConfigError
from viena.common.twin.serial_port import SerialEndpoint

from .errors import GnssErrorModel, SkyModel
from .nmea_twin import NmeaTwin
from .novatel_twin import NovatelTwin
from .replay import DRIVE_CSV, DriveReplay, RecordedEpoch, load_drive
from .solution import Solution, TruthSolver

#: Settings of a GNSS twin in the sim's [sim.<name>] table, with their defaults.
TWIN_SETTINGS = {
    "port": 0,
    "lever_arm_m": [0.0, 0.0, 0.0],
    "seed": -1,                      # -1: from the sim's seed and the device's name
    "cep_m": -1.0,                   # -1: the receiver's own (NovAtel 1.8 m, u-blox 2.5 m)
    "outage_interval_s": 64.0,       # mean time between INSUFFICIENT_OBS periods; 0 = none
    "undulation_m": 55.0,            # geoid height used to split BESTPOS/GGA heights
    "replay": "",                    # "", "drive" (data/ 2016 drive) or a CSV path
    "replay_speed": 1.0,
    "replay_loop": True,
    "replay_retime": True,           # move the recording's epochs to the present
    "rate_hz": 10.0,                 # NMEA only: epochs per second
}


def _replay(value: str, source: str):
    if not value:
        return None
    path = DRIVE_CSV if value == "drive" else Path(value)
    try:
        return load_drive(path)
    except (OSError, KeyError, ValueError) as exc:
        raise ConfigError(f"{source}: cannot replay {str(path)!r}: {exc}") from None


def _common(name: str, table: dict, service) -> tuple[dict, dict]:
    source = f"{getattr(service.args, 'config', None)} [sim.{name}]"
    s = merge_settings(TWIN_SETTINGS, table, source)
    if len(s["lever_arm_m"]) != 3:
        raise ConfigError(f"{source}: setting 'lever_arm_m' must be 3 numbers")
    seed = s["seed"] if s["seed"] >= 0 else (
        int(service.settings.get("seed", 0)) * 1000 + zlib.crc32(name.encode()) % 1000)
    kwargs = dict(lever_arm_m=[float(v) for v in s["lever_arm_m"]], seed=seed,
                  outage_interval_s=s["outage_interval_s"], undulation_m=s["undulation_m"],
                  replay=_replay(s["replay"], source), replay_speed=s["replay_speed"],
                  replay_loop=s["replay_loop"], replay_retime=s["replay_retime"])
    if s["cep_m"] > 0:
        kwargs["cep_m"] = s["cep_m"]
    return s, kwargs


def make_novatel_device(name: str, table: dict, car, service) -> SerialEndpoint:
    """Factory for the sim (kind = "novatel")."""
    s, kwargs = _common(name, table, service)
    twin = NovatelTwin(None if kwargs["replay"] else car.truth, **kwargs)
    return SerialEndpoint(twin, service.settings.get("host", "127.0.0.1"), s["port"], name).start()


def make_nmea_device(name: str, table: dict, car, service) -> SerialEndpoint:
    """Factory for the sim (kind = "nmea")."""
    s, kwargs = _common(name, table, service)
    twin = NmeaTwin(None if kwargs["replay"] else car.truth, rate_hz=s["rate_hz"], **kwargs)
    return SerialEndpoint(twin, service.settings.get("host", "127.0.0.1"), s["port"], name).start()


__all__ = ["NovatelTwin", "NmeaTwin", "make_novatel_device", "make_nmea_device",
           "DriveReplay", "RecordedEpoch", "load_drive", "DRIVE_CSV", "GnssErrorModel",
           "SkyModel", "Solution", "TruthSolver", "TWIN_SETTINGS"]
