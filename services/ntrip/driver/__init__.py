"""The NTRIP client's protocol side (bytes in, typed values out). No zenoh, no msgpack.

- :mod:`.client`: the connection loop on viena.common.clock, its state and counters;
- :mod:`.retry`: when the next attempt may start (the 10 s rule, the backoff);
- :mod:`.caster`: one connection: TCP/TLS, request, answer, the (chunked) stream;
- :mod:`.protocol`: the request, answer, source table and GGA pieces of pygnssutils;
- :mod:`.rtcm3`: whole, checked RTCM 3 frames out of the stream;
- :mod:`.sourcetable`: a source table's mountpoints, with distances;
- :mod:`.credentials`: the login, from a file only its owner reads.
"""
from .caster import CasterAddress, CasterLink, LinkError, fetch_sourcetable
from .client import ClientConfig, NtripClient
from .credentials import Credentials, CredentialsError, read_credentials
from .protocol import NtripProtocol, Position
from .retry import RetryPolicy
from .rtcm3 import Batch, Rtcm3Framer

__all__ = [name for name in dir() if not name.startswith("_")]
