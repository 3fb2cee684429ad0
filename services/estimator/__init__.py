"""The estimator: the car's attitude, position and velocity from its IMU and GNSS samples.

`Estimator` is the whole filter as a plain class (no zenoh); `service.py` runs it on zenoh.
"""
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.settings import EstimatorSettings
from viena.services.estimator.state import STATE

__all__ = ["Estimator", "EstimatorSettings", "STATE"]
