"""Replay recorded states through the sensor models and compare with the recorded readings.

With the states of a dataset (truth when simulated, the car's on-line estimate in the real
runs) and its inputs, every sensor model predicts what the sensors should have read. The
residuals per channel show how well the model (and the geometry) explains the data; large or
structured residuals point at a missing effect.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from crs_core.analysis.statistics import summary
from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.parameters import ParameterSet


def predicted_samples(dataset: Dataset, model: CarModel, params: ParameterSet | None = None):
    """Model prediction of ``y`` (N, 13) from the dataset's states and commanded inputs."""
    if dataset.x is None:
        raise FieldError("dataset", "has no state trajectory x.npy to replay")
    if dataset.u is None:  # the front wheel speeds depend on the steering angle
        raise FieldError("dataset", "has no inputs u.npy; the sensor-model replay needs them")
    params = params or model.parameters.updated(
        {n: v.value for n, v in dataset.geometry.parameters().items() if n in model.parameters}
    )
    p = params.vector()
    numeric = model.numeric
    out = np.empty((len(dataset.t), len(Y_CHANNELS)))
    for k, (x, u) in enumerate(zip(dataset.x, dataset.u, strict=True)):
        y = numeric.outputs(model.initial_state(x[:6], u), u, p)
        out[k, 0:4] = y["lighthouse/0/1"]
        out[k, 4:8] = y["lighthouse/0/2"]
        out[k, 8:12] = y["wheel_encoders"]
        out[k, 12] = y["imu"][2]
    return out


def channel_errors(dataset: Dataset, model: CarModel | None = None) -> dict[str, Any]:
    """Median and 95th percentile of ``|recorded - predicted|`` per channel of ``y``.

    Units: rad for Lighthouse rows, rad/s for wheel speeds and yaw rate. NaN samples are skipped.
    """
    model = model or CarModel(n_base_stations=len(dataset.geometry.known_stations()))
    residual = dataset.y - predicted_samples(dataset, model)
    out = {}
    for name, column in zip(Y_CHANNELS, residual.T, strict=True):
        column = np.abs(column[np.isfinite(column)])
        out[name] = {**summary(column, ("median", "p95")), "samples": int(column.size)}
    return out
