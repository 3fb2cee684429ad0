"""GNSS receivers: NovAtel OEM4 binary and NMEA, in the three rooms of docs/dataflow.md#rooms.

- ``driver``: the wire protocols, bytes in, typed values out (no zenoh, no msgpack);
- the viena.gnss.fix/1 sample (schema, reader, monitor view) is a contract: common/samples/fix.py;
- ``fixes``: how each receiver's logs become fix samples;
- ``service``: ``viena-gnss``, the zenoh glue;
- ``simulator``: the receivers' twins and the replay of the car's 2016 drive;
- ``bench``: ``viena bench gnss``.
"""
