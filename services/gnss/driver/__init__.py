"""GNSS receivers' wire protocols (bytes in, typed values out). No zenoh, no msgpack.

- :mod:`.novatel`: NovAtel OEM4 binary (BESTXYZ/BESTPOS/BESTVEL, commands, start-up).
- :mod:`.nmea`: NMEA 0183 receivers (GGA/RMC/VTG/GSA/GSV) via pynmea2.
- :mod:`.gpstime`: GPS week/ms <-> UTC with the leap-second table.
"""
from .gpstime import gps_to_utc_ns, utc_to_gps
from .nmea import NmeaDecoder, NmeaFix, NmeaReceiver
from .novatel import (
    BestPos,
    BestVel,
    BestXyz,
    CommandError,
    CommandTimeout,
    LogMessage,
    LogRequest,
    NovatelReceiver,
    StartupConfig,
)

__all__ = [name for name in dir() if not name.startswith("_")]
