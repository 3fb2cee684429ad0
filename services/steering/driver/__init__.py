"""The EPOS 70/10 steering drive on CANopen: no zenoh, no msgpack; usable from a shell."""
from viena.services.steering.driver.emcy import Emcy, emcy_name
from viena.services.steering.driver.epos import EDS_PATH, DriveError, DriveSettings, EposDrive, Feedback

__all__ = ["EDS_PATH", "DriveError", "DriveSettings", "Emcy", "EposDrive", "Feedback", "emcy_name"]
