"""Shared runs and helpers of the simulator tests (test_simulator.py, test_result.py)."""

from __future__ import annotations

import numpy as np

from crs_core.model import CarModel
from sim import SensorSpec, SensorSuite, SimulationResult

REST_DURATION = 10.0
DRIVE_DURATION = 2.0  # the car stays inside the Lighthouse coverage for ~2.6 s with DRIVE
IMU_BIAS = (0.1, -0.2, 0.03)
#: Default noise everywhere, a bias on the IMU, and a motion-capture pose stream switched on.
NOISY = SensorSuite(
    imu=SensorSpec(250.0, (0.5, 0.5, 0.05), bias=IMU_BIAS),
    pose=SensorSpec(100.0, (0.002, 0.002, 0.01)),
)
IDEAL = SensorSuite().ideal()
AT_REST = np.zeros(6)


def constant(steer: float, torque: float):
    """A controller that always commands ``[steer, torque]``."""
    command = np.array([steer, torque])
    return lambda t, x: command.copy()


REST = constant(0.0, 0.0)
DRIVE = constant(0.1, 0.3)
STRAIGHT = constant(0.0, 0.3)


def truth_index(result: SimulationResult, times: np.ndarray) -> np.ndarray:
    """Indices of the dense truth samples at ``times`` (which must be integration points)."""
    index = np.clip(np.searchsorted(result.truth_t, times - 1e-12), 0, result.truth_t.size - 1)
    assert np.allclose(result.truth_t[index], times, rtol=0, atol=1e-12), "not a truth point"
    return index


def model_outputs(model: CarModel, x: np.ndarray, u: np.ndarray, sensor: str) -> np.ndarray:
    """Noise-free model output of ``sensor`` for every row of base states ``x``."""
    p = model.parameters.vector()
    return np.stack([model.numeric.outputs(xi, u, p)[sensor] for xi in x])


def first_crossing(t: np.ndarray, v: np.ndarray, level: float) -> float:
    """First time ``v`` rises above ``level`` (linear interpolation between samples)."""
    k = int(np.argmax(v > level))
    assert k > 0 and v[k] > level
    return float(t[k - 1] + (level - v[k - 1]) * (t[k] - t[k - 1]) / (v[k] - v[k - 1]))
