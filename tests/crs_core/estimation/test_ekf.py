"""Tests of crs_core.estimation.ekf: the EKF's prediction and update against the Kalman filter
equations computed here."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.estimation.ekf import EkfSteps
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import Measurement
from crs_core.model import MAX_SUBSTEP, CarModel

X = np.array([0.5, -0.2, 0.3, 1.0, 0.1, 0.5])
U = np.array([0.1, 0.4])


@pytest.fixture(scope="module")
def model() -> CarModel:
    return CarModel()


@pytest.fixture(scope="module")
def steps(model: CarModel) -> EkfSteps:
    return EkfSteps(model, EstimatorNoise(), gate_probability=0.9999)


def test_a_pose_update_is_the_kalman_update(steps: EkfSteps):
    """The pose sensor reads (x, y, yaw): ``K = P H' (H P H' + R)^-1``, ``x + K (z - H x)`` and
    ``(I - K H) P``, with ``R`` the assumed pose noise."""
    a = np.random.default_rng(0).normal(size=(6, 6))
    P = 0.01 * (a @ a.T + np.eye(6))
    z = X[:3] + np.array([0.004, -0.003, 0.01])
    result = steps.update(X, P, U, Measurement(0.0, "pose", z))
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    R = np.diag(np.square(EstimatorNoise().pose_std))
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    np.testing.assert_allclose(np.ravel(result.x), X + K @ (z - H @ X), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.array(result.P), (np.eye(6) - K @ H) @ P, rtol=0, atol=1e-12)
    assert result.defined and result.within_gate and result.finite and result.closer


def test_a_pose_far_outside_the_gate_is_flagged(steps: EkfSteps):
    P = 1e-4 * np.eye(6)
    result = steps.update(X, P, U, Measurement(0.0, "pose", X[:3] + np.array([2.0, 0.0, 0.0])))
    assert not result.within_gate


def test_prediction_follows_the_model_and_adds_the_process_noise(model: CarModel, steps: EkfSteps):
    """From a certain state, one substep gives the model's RK4 step and ``diag(q)^2 h``."""
    h = 0.5 * MAX_SUBSTEP
    x, P = steps.predict(X, np.zeros((6, 6)), U, h)
    np.testing.assert_allclose(
        np.ravel(x), model.numeric.step(X, U, model.parameters.vector(), h), rtol=0, atol=1e-12
    )
    q = EstimatorNoise().process_std_for(model)
    np.testing.assert_allclose(np.array(P), np.diag(np.square(q)) * h, rtol=1e-12, atol=0)
    x0, P0 = steps.predict(X, np.eye(6), U, 0.0)  # no time: nothing changes
    np.testing.assert_array_equal(x0, X)
    np.testing.assert_array_equal(P0, np.eye(6))
