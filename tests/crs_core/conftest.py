"""Fixtures shared by the crs_core tests: a short simulated dataset, its saved folder (and a
copy to break), and a recording written the way a user would."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

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


@pytest.fixture
def corruptible(saved: Path, tmp_path: Path) -> Path:
    """A fresh copy of the saved dataset, to be broken by a test."""
    return Path(shutil.copytree(saved, tmp_path / "broken"))


def write_user_recording(folder: Path) -> dict:
    """A recording written the way a user would, with numpy and PyYAML only (no project code).

    Two base stations; station 1 plane 2 and a gyro are recorded, one wheel-encoder row is NaN
    (a missing sample), the stamps are Unix-like and the stream arrays unsorted.
    """
    folder.mkdir()
    rng = np.random.default_rng(0)
    t = 1.7e9 + np.arange(25) * 0.02
    np.save(folder / "t.npy", t)
    np.save(folder / "y.npy", np.full((13, t.size), np.nan))
    stations = [
        {"rotation": np.eye(3).tolist(), "position": [0.0, 0.0, 2.0], "dt1": 0.0, "dt2": 0.0},
        {
            "rotation": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            "position": [1.0, -0.5, 2.2],
            "dt1": -0.01,
            "dt2": 0.02,
        },
    ]
    diodes = [[-0.045, 0.015], [-0.06, 0.015], [-0.045, -0.015], [-0.06, -0.015]]
    meta = {"source": "my-lab", "geometry": {"base_stations": stations, "photodiodes": diodes}}
    (folder / "dataset.yaml").write_text(yaml.safe_dump(meta))
    lh_t = t[::-1] + 0.001
    arrays = {
        "meas:lighthouse__1__2:t": lh_t,
        "meas:lighthouse__1__2:v": rng.normal(0.0, 0.3, (t.size, 4)),
        "meas:gyro:t": np.arange(100) * 0.004 + 1.7e9,
        "meas:gyro:v": rng.normal(0.0, 1.0, (100, 1)),
        "meas:wheel_encoders:t": np.arange(100) * 0.004 + 1.7e9,
        "meas:wheel_encoders:v": rng.normal(50.0, 5.0, (100, 4)),
        "inputs:t": t[::2],
        "inputs:u": np.column_stack([np.full(13, 0.2), np.full(13, 0.5)]),  # steer, torque
    }
    arrays["meas:wheel_encoders:v"][7, 2] = np.nan
    np.savez(folder / "stream.npz", **arrays)
    return arrays
