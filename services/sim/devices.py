"""The device twins the simulated car serves, chosen by configuration.

Each device has a table in the sim's settings, e.g.

    [sim]
    devices = ["gnss0", "razor0"]
    [sim.gnss0]
    kind = "novatel"          # novatel | nmea | razor | epos
    port = 5001               # TCP port on the sim's host (0 = any free port)

A kind maps to a factory `make(name, table, car, service) -> device`, where a device has
`.url` (what the driver opens) and `.stop()`. Factories live with their device's simulator.

A port is the device's cable: a serial twin serves one host at a time, and every twin
only this machine's processes of the sim's own user, or other machines if `host` lets them
(common/twin/peers.py; services/sim/README.md, "The twins' ports").
"""
from __future__ import annotations

import importlib
from typing import Any

from viena.common.errors import ConfigError

#: kind -> "module:factory"; the module is imported only when the kind is used
KINDS = {
    "novatel": "viena.services.gnss.simulator:make_novatel_device",
    "nmea": "viena.services.gnss.simulator:make_nmea_device",
    "razor": "viena.services.imu.simulator:make_razor_device",
    "epos": "viena.services.steering.simulator:make_epos_device",
}


def start_devices(service, car) -> list[Any]:
    devices = []
    tables = service.toml.get("sim", {})
    for name in service.settings.devices:
        table = dict(tables.get(name, {}))
        kind = table.pop("kind", None)
        source = f"{service.args.config} [sim.{name}]"
        if kind not in KINDS:
            raise ConfigError(f"{source}: setting 'kind' must be one of {sorted(KINDS)}, got {kind!r}")
        module, factory = KINDS[kind].split(":")
        make = getattr(importlib.import_module(module), factory)
        device = make(name, table, car, service)
        service.log.info("device %s (%s) at %s", name, kind, device.url)
        devices.append(device)
    return devices
