"""The estimator: the car's attitude, position and velocity from its IMU and GNSS samples.

`Estimator` is the whole filter as a plain class (no zenoh); `service.py` runs it on zenoh.
"""
from viena.common.samples.estimator import STATE
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.settings import EstimatorSettings

__all__ = ["Estimator", "EstimatorSettings", "STATE"]
