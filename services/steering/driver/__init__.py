"""The EPOS 70/10 steering drive on CANopen: no zenoh, no msgpack; usable from a shell."""
from viena.services.steering.driver.emcy import Emcy, emcy_name
from viena.services.steering.driver.epos import EDS_PATH, DriveError, DriveSettings, EposDrive, Feedback
from viena.services.steering.model import ds402  # the DS402 words: plain data, in the model

__all__ = ["EDS_PATH", "ds402", "DriveError", "DriveSettings", "Emcy", "EposDrive", "Feedback", "emcy_name"]
