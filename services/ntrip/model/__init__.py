"""The NTRIP client's samples: the corrections (viena.gnss.corrections/1) and the client's
state (viena.ntrip.state/1). No zenoh, no msgpack, no I/O."""
