"""Tests of crs_core.estimation.readout: the MHE's read-out from its newest node to a query."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.estimation.noise import EstimatorNoise
from crs_core.estimation.readout import ForwardReadOut
from crs_core.measurements import Measurement
from crs_core.model import CarModel

X = np.array([0.5, -0.2, 0.3, 1.0, 0.1, 0.5])
P = 1e-3 * np.eye(6)


@pytest.fixture(scope="module")
def model() -> CarModel:
    return CarModel()


@pytest.fixture(scope="module")
def read_out(model: CarModel) -> ForwardReadOut:
    return ForwardReadOut(model, EstimatorNoise())


def test_without_data_the_node_is_carried_by_the_model(model, read_out):
    """The state at the query is the model's step from the node under the command in force at
    the node; the covariance grows."""
    p = model.parameters.vector()

    def command_at(s: float) -> np.ndarray:
        return np.array([0.1 if s < 1.02 else 0.25, 0.4])

    x, covariance = read_out(1.0, X, P, 1.05, [], command_at)
    np.testing.assert_allclose(np.ravel(x), model.numeric.step(X, command_at(1.0), p, 0.05))
    assert np.trace(np.array(covariance)) > np.trace(P)


def test_a_pose_reading_pulls_the_state_and_an_outlier_is_skipped(model, read_out):
    def command_at(s: float) -> np.ndarray:
        return np.array([0.1, 0.4])

    alone, _ = read_out(1.0, X, P, 1.05, [], command_at)
    seen = model.numeric.step(X, command_at(1.0), model.parameters.vector(), 0.02)
    reading = seen[:3] + np.array([0.01, 0.0, 0.0])
    pulled, covariance = read_out(1.0, X, P, 1.05, [Measurement(1.02, "pose", reading)], command_at)
    assert float(np.ravel(pulled)[0]) > float(np.ravel(alone)[0]) + 1e-3
    assert np.trace(np.array(covariance)[:3, :3]) < np.trace(P[:3, :3])
    outlier = Measurement(1.02, "pose", seen[:3] + np.array([2.0, 0.0, 0.0]))
    skipped, _ = read_out(1.0, X, P, 1.05, [outlier], command_at)
    # the same prediction, only split at the outlier's stamp
    np.testing.assert_allclose(np.ravel(skipped), np.ravel(alone), rtol=0, atol=1e-6)
