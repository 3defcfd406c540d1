"""State estimation: EKF and moving horizon estimation behind one interface."""

from crs_core.estimation.base import Estimate, Estimator, parse_sensor_set
from crs_core.estimation.ekf import EkfSettings, ExtendedKalmanFilter
from crs_core.estimation.factory import make_estimator
from crs_core.estimation.noise import EstimatorNoise

__all__ = [
    "EkfSettings",
    "Estimate",
    "Estimator",
    "EstimatorNoise",
    "ExtendedKalmanFilter",
    "make_estimator",
    "parse_sensor_set",
]
