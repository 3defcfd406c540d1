"""Fixtures shared by the crs_core tests: a short simulated dataset and its saved folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.model import CarModel
from sim import SensorSuite, Simulator


def weaving(t: float, x: np.ndarray) -> np.ndarray:
    """Varying steer so that the two input columns are distinguishable."""
    return np.array([0.15 * np.sin(3.0 * t), 0.25])


@pytest.fixture(scope="module")
def simulated() -> Dataset:
    result = Simulator(CarModel(), SensorSuite(), seed=3).run(weaving, 2.0, np.zeros(6))
    data = result.to_dataset()
    data.y[3, 12] = np.nan  # a missing yaw rate must survive the round trip
    return data


@pytest.fixture(scope="module")
def saved(simulated: Dataset, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulated.save(tmp_path_factory.mktemp("dataset") / "run")
