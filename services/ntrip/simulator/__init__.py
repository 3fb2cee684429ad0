"""The NTRIP caster's twin and the RTCM 3 it serves, so the corrections chain runs with
real bytes (issue 28).

- ``rtcm``: RTCM 3 messages built from their fields with pyrtcm's own tables (1002, 1004,
  1005, 1006, 1033, MSM4 1074/1084), framed by pyrtcm;
- ``sky``: GPS on the 24-slot almanac geometry, GLONASS on its 24 slots;
- ``base``: a reference station at a baseline from the sim's origin, and what it measures
  each epoch (pseudoranges, carrier phases, lock times);
- ``schedule``: which messages go when (observables 1 Hz, 1005/1006 every 10 s and at
  connect, 1033 every 30 s), as frames;
- ``protocol``: what an NTRIP 1.0/2.0 caster says (responses, the source table);
- ``caster``: `CasterTwin`, the caster on a local port, with the faults real casters have;
  ``answer`` answers one connection, ``stream`` streams RTCM to it, ``mountpoint`` and
  ``clients`` are what it serves and what it keeps of each connection;
- ``timebase``: the caster's GPS time (real, or faster for tests);
- ``credentials``: its login file, made when missing;
- ``__main__``: ``python -m viena.services.ntrip.simulator`` (one caster, one mountpoint).
"""
from .base import BaseStation, Epoch, Observation, place
from .caster import CasterTwin, Client, Mountpoint, Sent
from .schedule import L1, MESSAGE_SETS, MSM, RTK, Frames, stream
from .timebase import Timebase

__all__ = ["BaseStation", "Epoch", "Observation", "place", "CasterTwin", "Client", "Mountpoint", "Sent",
           "L1", "MESSAGE_SETS", "MSM", "RTK", "Frames", "stream", "Timebase"]
