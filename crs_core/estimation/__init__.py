"""State estimation: EKF and moving horizon estimation behind one interface, and the
real-time policy that drives one on a live stream."""

from crs_core.estimation.base import Estimate, Estimator, EstimatorSettings, parse_sensor_set
from crs_core.estimation.ekf import EkfSettings, ExtendedKalmanFilter
from crs_core.estimation.factory import INPUT_MODES, KINDS, input_free_model, make_estimator
from crs_core.estimation.health import HealthSettings
from crs_core.estimation.initialization import InitializationSettings
from crs_core.estimation.inputs import InputModeEstimator
from crs_core.estimation.lighthouse_pose import (
    LighthouseFixes,
    LighthousePoseSolver,
    PoseFix,
    SweepPairer,
)
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.estimation.noise import EstimatorNoise
from crs_core.estimation.realtime import (
    RealtimeEstimator,
    RealtimeSettings,
    RealtimeWarning,
    UpdateResult,
)

__all__ = [
    "INPUT_MODES",
    "KINDS",
    "EkfSettings",
    "Estimate",
    "Estimator",
    "EstimatorNoise",
    "EstimatorSettings",
    "ExtendedKalmanFilter",
    "HealthSettings",
    "InitializationSettings",
    "InputModeEstimator",
    "LighthouseFixes",
    "LighthousePoseSolver",
    "MheSettings",
    "MovingHorizonEstimator",
    "PoseFix",
    "RealtimeEstimator",
    "RealtimeSettings",
    "RealtimeWarning",
    "SweepPairer",
    "UpdateResult",
    "input_free_model",
    "make_estimator",
    "parse_sensor_set",
]
