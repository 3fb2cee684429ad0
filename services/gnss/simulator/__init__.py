"""GNSS receivers' twins: NovAtel OEM4 (binary) and NMEA, from the simulated car's truth
or replaying the car's real 2016 drive, served to the unchanged drivers over socket://.

The sim builds them from its settings (``[sim.<name>]`` tables, see ``TWIN_SETTINGS``)::

    [sim.gnss0]
    kind = "novatel"                 # or "nmea"
    port = 0                         # TCP port (0 = any free one)
    lever_arm_m = [-0.4, 1.0, 1.5]   # antenna in the body frame (x right, y forward, z up)
    replay = ""                      # "" live from truth; "drive" = the 2016 drive; or a CSV
    com2_port = 5011                 # NovAtel: serve its COM2 too (corrections beside COM1); -1: not
    model = "RT2WA"                  # NovAtel: what VERSION says; RT2... fixes, RT20... floats on L1,
    firmware = "2.310"               # others take pseudorange corrections only (rtk.py)

All live twins of one simulated car share one sky (`CommonErrors`: satellite clock, orbit
and atmosphere errors), drawn from the sim's seed; each keeps its own multipath, noise and
satellite selection. Their errors are a standalone receiver's (errors.py, profile
"standalone": steps when the satellites change, multipath bursts, heavy tails), not the
estimator's own model.

A NovAtel twin takes RTCM 3 corrections on a port set to INTERFACEMODE RTCMV3 (its COM1,
or its COM2 when ``com2_port`` serves it) and moves through the differential solution
types as an OEM4 does (rtk.py: PSRDIFF, float, fixed; differential.py: their errors).
"""
from __future__ import annotations

import weakref
import zlib
from pathlib import Path

import numpy as np

from viena.common.config import merge_settings
from viena.common.errors import ConfigError
from viena.common.twin.serial_port import SerialEndpoint, serve_twin

from .errors import CommonErrors, GnssErrorModel, SkyModel
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
    "shared_sky": True,              # the car's sky: its receivers share clock, orbit, atmosphere
    "sbas_enable_value": 0,          # NovAtel only: the binary SBASCONTROL keyword its firmware
                                     # reads as ENABLE (OEM4 2.310 manual: 0; later firmware: 1)
    "com2_port": -1,                 # NovAtel only: TCP port of its COM2 (0 = any free one); -1: none
    "model": "RT2WA",                # NovAtel only: the model VERSION says (RT2... RT-2, RT20... RT-20)
    "firmware": "2.310",             # NovAtel only: the firmware VERSION says
}

#: one sky per simulated car
_SKIES: weakref.WeakKeyDictionary[object, CommonErrors] = weakref.WeakKeyDictionary()


def car_sky(car, seed: int) -> CommonErrors:
    """The error sources every receiver on `car` shares, made on first use."""
    sky = _SKIES.get(car)
    if sky is None:
        sky = _SKIES[car] = CommonErrors(np.random.default_rng([seed, zlib.crc32(b"sky")]))
    return sky


def _replay(value: str, source: str):
    if not value:
        return None
    path = DRIVE_CSV if value == "drive" else Path(value)
    try:
        return load_drive(path)
    except (OSError, KeyError, ValueError) as exc:
        raise ConfigError(f"{source}: cannot replay {str(path)!r}: {exc}") from None


def _common(name: str, table: dict, car, service) -> tuple[dict, dict]:
    source = f"{getattr(service.args, 'config', None)} [sim.{name}]"
    s = merge_settings(TWIN_SETTINGS, table, source)
    if len(s["lever_arm_m"]) != 3:
        raise ConfigError(f"{source}: setting 'lever_arm_m' must be 3 numbers")
    seed = s["seed"] if s["seed"] >= 0 else (
        service.settings.seed * 1000 + zlib.crc32(name.encode()) % 1000)
    replay = _replay(s["replay"], source)
    shared = s["shared_sky"] and replay is None
    kwargs = dict(lever_arm_m=[float(v) for v in s["lever_arm_m"]], seed=seed,
                  outage_interval_s=s["outage_interval_s"], undulation_m=s["undulation_m"],
                  replay=replay, replay_speed=s["replay_speed"],
                  replay_loop=s["replay_loop"], replay_retime=s["replay_retime"],
                  common_errors=car_sky(car, service.settings.seed) if shared else None)
    if s["cep_m"] > 0:
        kwargs["cep_m"] = s["cep_m"]
    return s, kwargs


class NovatelDevice:
    """A NovAtel twin served on its ports: ``url`` is COM1's (commands and logs), ``urls``
    names every port served (COM2 for corrections when configured)."""

    def __init__(self, twin: NovatelTwin, endpoints: dict):
        self.twin = twin
        self.endpoints = endpoints
        self.url = endpoints["COM1"].url
        self.urls = {port: e.url for port, e in endpoints.items()}

    def health(self) -> dict:
        """What corrections came to at this receiver (NovatelTwin.corrections_health)."""
        return self.twin.corrections_health()

    def stop(self) -> None:
        for e in self.endpoints.values():
            e.stop()


def make_novatel_device(name: str, table: dict, car, service) -> NovatelDevice:
    """Factory for the sim (kind = "novatel"): COM1 as ``name``, COM2 as ``name.com2``."""
    s, kwargs = _common(name, table, car, service)
    if s["sbas_enable_value"] not in (0, 1):
        raise ConfigError(f"[sim.{name}]: setting 'sbas_enable_value' must be 0 or 1")
    twin = NovatelTwin(None if kwargs["replay"] else car.truth, sbas_enable_value=s["sbas_enable_value"],
                       model=s["model"], firmware=s["firmware"], **kwargs)
    host = service.settings.host
    endpoints = {"COM1": serve_twin(twin, name, host, s["port"])}
    if s["com2_port"] >= 0:
        endpoints["COM2"] = serve_twin(twin.port("COM2"), f"{name}.com2", host, s["com2_port"])
    return NovatelDevice(twin, endpoints)


def make_nmea_device(name: str, table: dict, car, service) -> SerialEndpoint:
    """Factory for the sim (kind = "nmea")."""
    s, kwargs = _common(name, table, car, service)
    twin = NmeaTwin(None if kwargs["replay"] else car.truth, rate_hz=s["rate_hz"], **kwargs)
    return serve_twin(twin, name, service.settings.host, s["port"])


__all__ = ["NovatelTwin", "NovatelDevice", "NmeaTwin", "make_novatel_device", "make_nmea_device",
           "DriveReplay", "RecordedEpoch", "load_drive", "DRIVE_CSV", "GnssErrorModel",
           "CommonErrors", "car_sky", "SkyModel", "Solution", "TruthSolver", "TWIN_SETTINGS"]
