"""NTRIP: RTK and DGPS corrections from a caster, for the receivers (issue 28).

- ``driver``: the NTRIP protocol on pygnssutils' pieces, the retry policy, RTCM 3 framing,
  the credentials file (no zenoh, no msgpack);
- its samples, viena.gnss.corrections/1 and viena.ntrip.state/1, are contracts: common/samples/;
- ``service``: ``viena-ntrip``, the zenoh glue;
- ``simulator``: the caster's twin and the RTCM 3 it serves.
"""
