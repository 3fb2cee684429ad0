"""The steering drive's twin and how the simulated car serves it.

    [sim.epos0]
    kind = "epos"
    port = 0                    # the slcan adapter's TCP port (0 = any free port)

The sim runs the twin on an in-process python-can `virtual` channel and serves that bus as
a serial CAN adapter (common/twin/slcan_hub.py); the steering service opens it with
`interface = "slcan"`, `channel = "socket://127.0.0.1:PORT"`. The twin turns the car's
wheels through `car.set_wheel_source`. In the lockstep runner (the sim's host "mem") the
twin is on the `lockstep` CAN interface instead, on a channel named after the device, and
the steering opens that channel with `interface = "lockstep"`.
"""
from __future__ import annotations

import itertools
import logging
import os
from dataclasses import fields

import canopen

from viena.common.errors import ConfigError
from viena.common.twin.slcan_hub import SlcanHub
from viena.services.steering.simulator.epos_twin import EposTwin, TwinSettings
from viena.services.steering.simulator.person import PersonAtTheWheel
from viena.services.steering.simulator.plant import CHIRP005, TRAJ01, PlantParams, PositionPlant

__all__ = ["EposDevice", "EposTwin", "PersonAtTheWheel", "PlantParams", "PositionPlant", "TwinSettings",
           "make_epos_device", "start_twin_on_hub"]

PLANTS = {"traj01": TRAJ01, "chirp005": CHIRP005}
_channels = itertools.count()


class EposDevice:
    """A twin on its own virtual CAN bus, served to other processes by an slcan hub (or,
    in the lockstep runner, on a lockstep channel of this process: no hub)."""

    def __init__(self, twin: EposTwin, hub: SlcanHub | None, network: canopen.Network, channel: str = ""):
        self.twin, self.hub, self.network, self.channel = twin, hub, network, channel

    @property
    def url(self) -> str:
        """The steering service's slcan channel (the lockstep channel's name in the runner)."""
        return self.hub.url if self.hub is not None else f"lockstep:{self.channel}"

    @property
    def port(self) -> int:
        return self.hub.port if self.hub is not None else 0

    def stop(self) -> None:
        self.twin.stop()
        self.network.disconnect()
        if self.hub is not None:
            self.hub.stop()


def start_twin_on_hub(settings: TwinSettings | None = None, host: str = "127.0.0.1",
                      port: int = 0, bitrate: int = 1_000_000) -> EposDevice:
    """A running twin reachable as `slcan` on socket://host:port."""
    channel = f"viena-epos-{os.getpid()}-{next(_channels)}"
    hub = SlcanHub(channel, host=host, port=port, bitrate=bitrate).start()
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.1
    network.connect(interface="virtual", channel=channel, receive_own_messages=False)
    twin = EposTwin(network, settings).start()
    return EposDevice(twin, hub, network)


def start_twin_in_lockstep(settings: TwinSettings | None, channel: str) -> EposDevice:
    """A running twin on the lockstep CAN channel `channel` (viena.common.lockstep.can)."""
    network = canopen.Network()
    network.connect(interface="lockstep", channel=channel, receive_own_messages=False)
    twin = EposTwin(network, settings).start()
    return EposDevice(twin, None, network, channel)


def make_epos_device(name: str, table: dict, car, service) -> EposDevice:
    """The sim's factory (services/sim/devices.py): settings from the [sim.<name>] table."""
    table = dict(table)
    port = table.pop("port", 0)
    bitrate = table.pop("bitrate", 1_000_000)
    plant = table.pop("plant", "traj01")
    known = {f.name for f in fields(TwinSettings)} - {"plant"}
    unknown = set(table) - known
    source = f"{getattr(service.args, 'config', None)} [sim.{name}]"
    if unknown:
        raise ConfigError(f"{source}: unknown setting '{sorted(unknown)[0]}' "
                          f"(known: bitrate, plant, port, {', '.join(sorted(known))})")
    if plant not in PLANTS:
        raise ConfigError(f"{source}: plant must be one of {sorted(PLANTS)}, got {plant!r}")
    try:
        settings = TwinSettings(plant=PLANTS[plant], **table)
    except TypeError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if logging.getLogger().getEffectiveLevel() > logging.DEBUG:
        logging.getLogger("canopen").setLevel(logging.WARNING)   # a line per SDO otherwise
    if service.settings.host == "mem":
        device = start_twin_in_lockstep(settings, name)
    else:
        device = start_twin_on_hub(settings, host=service.settings.host, port=int(port), bitrate=int(bitrate))
    car.set_wheel_source(device.twin.wheel_angle_rad)
    device.twin.person.hands = car.driver_wheel_angle       # a person drives while the drive is off
    return device
