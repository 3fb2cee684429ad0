"""The contracts: every sample that crosses a process, and the one table of the car's topics.

One module per schema, each with its schema (`common/schema.py`), the typed reader its
consumers use and its monitor view; none of them loads I/O (tests/test_import_purity.py):

- ``fix``          viena.gnss.fix/1          a GNSS receiver's solution
- ``corrections``  viena.gnss.corrections/1  RTCM from an NTRIP caster, for the receivers
- ``ntrip``        viena.ntrip.state/1       the NTRIP client's link
- ``imu``          viena.imu.sample/1        the Razor's calibrated sample
- ``steering``     viena.steering.state/1    the steering drive and its envelope, the trip causes
- ``estimator``    viena.estimator.state/2   the car's attitude, position and velocity
- ``pilot``        viena.pilot.state/1, viena.pilot.path/1   the route follower
- ``truth``        viena.sim.truth/1         the simulated car's ground truth
- ``health``       viena.health/1            every process, once a second

``topics`` says where each travels: key pattern, schema, producer, rate, reliability. The
services, the monitor, ``viena list``/``info``, the Foxglove bridge and the recorder read
it; no key is spelled anywhere else (tests/test_topics.py). How a schema may change
without breaking older recordings: ``docs/dataflow.md#evolving-a-schema``, checked by
tests/test_schema_history.py on stored samples of every earlier version.
"""
