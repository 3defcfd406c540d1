"""Fixtures of the calibration tests: two stand-in stations, the compiled sweep model and the
error of a fitted station."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.calibration.sweep_model import SweepModel
from crs_core.model.chronos import default_base_stations
from crs_core.model.lighthouse import BaseStation

STATIONS = default_base_stations(2)


def _errors(fitted: BaseStation, truth: BaseStation) -> tuple[float, float]:
    """Position error (m) and rotation error (rad, angle of the relative rotation)."""
    position = float(np.linalg.norm(np.array(fitted.position) - truth.position))
    relative = fitted.rotation.T @ truth.rotation
    angle = math.acos(max(-1.0, min(1.0, (np.trace(relative) - 1) / 2)))
    return position, angle


@pytest.fixture(scope="module")
def sweep_model() -> SweepModel:
    return SweepModel()
