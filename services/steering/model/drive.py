"""What the host knows of the EPOS drive without talking to it: its settings and its last
feedback, as plain data. The core (model/core.py) and the driver (driver/epos.py) both use
them; living here, they load no CAN stack (python-can, canopen, serial) into the model.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from viena.common.settings import setting
from viena.services.steering.model import ds402

#: the corrected EDS shipped with this package (see the comment at its top)
EDS_PATH = Path(__file__).resolve().parents[1] / "maxon-70_10.eds"

POSITION_MODE = -1
NMT_OPERATIONAL = 0x05
NMT_BOOTUP = 0x00


@dataclass
class DriveSettings:
    interface: str = setting("socketcan", "python-can interface: socketcan on the car, slcan for "
                                          "a serial adapter or the twin")
    channel: str = setting("can0", "CAN channel: can0, or socket://HOST:PORT for slcan")
    bitrate: int = setting(1_000_000, "CAN bit rate")
    node_id: int = setting(1, "the drive's CANopen node id")
    #: node id the host's heartbeat is sent with (0x700 + id); the drive consumes it
    host_node_id: int = setting(100, "node id of the host's heartbeat, which the drive consumes")
    sync_period_s: float = setting(0.01, "SYNC period: each SYNC brings the feedback TPDOs")
    #: drive heartbeat period (0x1017) and how long the host waits before calling it lost
    drive_heartbeat_period_s: float = setting(0.1, "the drive's heartbeat period (0x1017)")
    drive_heartbeat_timeout_s: float = setting(0.35, "no drive heartbeat this long: lost")
    #: host heartbeat period and how long the drive waits before faulting (0x1016)
    host_heartbeat_period_s: float = setting(0.05, "the host's heartbeat period")
    host_heartbeat_timeout_s: float = setting(0.25, "no host heartbeat this long: the drive faults "
                                                    "(0x1016)")
    #: sensor configuration 0x2210: HEDR-55L2 3600 pulses, type 2 = without index (the
    #: index track of the car's encoder is damaged), polarity 0
    encoder_pulses: int = setting(3600, "encoder pulses per turn (0x2210, HEDR-55L2)")
    sensor_type: int = setting(2, "encoder type (0x2210): 2 = without index, the car's is damaged")
    sensor_polarity: int = setting(0, "encoder polarity (0x2210)")
    max_following_error_qc: int = setting(7500, "the drive faults beyond this following error (0x6065)")
    sdo_timeout_s: float = setting(0.3, "longest wait for an SDO answer")
    #: extra python-can arguments, e.g. {"sleep_after_open": 0} for an slcan socket
    bus_options: dict[str, Any] = setting({}, "extra python-can arguments; for slcan on socket:// "
                                              "the driver adds sleep_after_open = 0, timeout = 0.01 and reads the "
                                              "socket in whole chunks (viena.common.urlhandler)")
    eds: str = setting(str(EDS_PATH), "the drive's object dictionary",
                       shown="the shipped services/steering/maxon-70_10.eds")


@dataclass(frozen=True)
class Feedback:
    """What the drive reported on the last SYNC (TPDO1 and TPDO2)."""
    statusword: int = 0
    position_qc: int = 0
    following_error_qc: int = 0
    demand_qc: int = 0
    op_mode: int = 0
    received_s: float = float("-inf")     # host monotonic time of the newest TPDO
    count: int = 0                        # TPDOs received since open

    @property
    def state(self) -> str:
        return ds402.state_of(self.statusword)
