"""One place that builds an estimator by name (nodes, benchmarks and bag replay use it)."""

from __future__ import annotations

from crs_core.estimation.base import Estimator
from crs_core.estimation.ekf import ExtendedKalmanFilter
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.model import CarModel


def make_estimator(
    kind: str,
    sensors: str,
    model: CarModel | None = None,
    rate_hz: float = 60.0,
    horizon: int = 40,
) -> Estimator:
    """``ekf`` or ``mhe`` on ``model`` (default: the Chronos model) with default tuning.

    ``rate_hz`` and ``horizon`` configure the MHE (the rate at which :meth:`estimate` will be
    called, and M); the event-driven EKF ignores them.
    """
    model = model or CarModel()
    if kind == "ekf":
        return ExtendedKalmanFilter(model, sensors)
    if kind == "mhe":
        return MovingHorizonEstimator(model, sensors, MheSettings(horizon=horizon, rate_hz=rate_hz))
    raise ValueError(f"estimator: must be 'ekf' or 'mhe', got {kind!r}")
