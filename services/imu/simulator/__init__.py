"""Twins of the Razor IMU for the simulated car (they plug into viena.common.twin.serial_port).

    twin = RazorTwin(car.truth)                          # VIENA firmware, the car's figures
    twin = RazorTwin(car.truth, RazorBoard(errors=NO_ERRORS))   # white noise and quantisation only
    twin = RazorAhrsTwin(car.truth)                      # stock Razor AHRS firmware
    twin = RazorReplayTwin.parked("speed_20hz")          # a real recording, as frames
    endpoint = SerialEndpoint(twin).start()              # driver opens endpoint.url
"""
from viena.common.config import merge_settings
from viena.common.errors import ConfigError
from viena.common.twin.serial_port import SerialEndpoint, serve_twin
from viena.services.imu.model.imu_errors import NO_ERRORS, ImuErrors
from viena.services.imu.simulator.board import CAR_RAZOR_ERRORS, LISBON_FIELD_ENU_NT, Measurement, RazorBoard
from viena.services.imu.simulator.razor_ahrs_twin import RazorAhrsTwin
from viena.services.imu.simulator.razor_twin import BANNER, RazorReplayTwin, RazorTwin


def make_twin(source: str, truth=None, **kwargs):
    """A twin by name, for settings files: "razor" (VIENA firmware, default), "razor-ahrs",
    "replay:<parked name>" or "replay:<path to a CSV recording>"."""
    if source in ("razor", "viena"):
        return RazorTwin(truth, **kwargs)
    if source == "razor-ahrs":
        return RazorAhrsTwin(truth, **kwargs)
    if source.startswith("replay:"):
        what = source.split(":", 1)[1]
        from viena.services.imu.recordings import PARKED
        if what in PARKED:
            return RazorReplayTwin.parked(what, **kwargs)
        return RazorReplayTwin(what, **kwargs)
    raise ValueError(f"unknown IMU twin {source!r}: razor, razor-ahrs, replay:<name or path>")


#: Settings of an IMU twin in the sim's [sim.<name>] table (kind = "razor"), with defaults.
TWIN_SETTINGS = {
    "port": 0,                 # TCP port (0 = any free one)
    "source": "razor",         # razor | razor-ahrs | replay:<parked name or CSV path>
    "boot_s": -1.0,            # -1: the twin's own (4 s of gyro averaging after reset)
    "seed": 0,
    "mount_zyx_deg": [0.0, 0.0, 0.0],   # how the board sits in the car (model/mount.py)
    "delay_s": 0.0,            # frames leave late by this much: the service stamps them late
    "errors": "car",           # car: the car's error figures (docs/sensors.md#imu-error-model); none: white only
}


def make_razor_device(name: str, table: dict, car, service) -> SerialEndpoint:
    """Factory for the sim (kind = "razor")."""
    source = f"{getattr(service.args, 'config', None)} [sim.{name}]"
    s = merge_settings(TWIN_SETTINGS, table, source)
    kwargs = {"seed": s["seed"]}
    if s["delay_s"]:
        kwargs["delay_s"] = s["delay_s"]
    if s["errors"] not in ("car", "none"):
        raise ConfigError(f"{source}: errors must be car or none, not {s['errors']!r}")
    if any(s["mount_zyx_deg"]) or s["errors"] == "none":
        kwargs["board"] = RazorBoard(mount_zyx_deg=tuple(s["mount_zyx_deg"]),
                                     errors=CAR_RAZOR_ERRORS if s["errors"] == "car" else NO_ERRORS)
    if s["boot_s"] >= 0:
        kwargs["boot_s"] = s["boot_s"]
    try:
        twin = make_twin(s["source"], car.truth, **kwargs)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return serve_twin(twin, name, service.settings.host, s["port"])


__all__ = ["make_razor_device", "TWIN_SETTINGS", "RazorBoard", "Measurement", "LISBON_FIELD_ENU_NT", "RazorTwin",
           "RazorReplayTwin", "RazorAhrsTwin", "BANNER", "make_twin", "CAR_RAZOR_ERRORS", "NO_ERRORS", "ImuErrors"]
