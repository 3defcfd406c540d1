"""Fixtures of the calibration tests: two stand-in stations, stations placed by where they look,
the compiled sweep model and the error of a fitted station."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.calibration.sweep_model import SweepModel
from crs_core.model.chronos import default_base_stations
from crs_core.model.lighthouse import BaseStation

STATIONS = default_base_stations(2)


def look_at(
    position: tuple[float, float, float],
    target: tuple[float, float, float] = (0.0, 0.0, 0.0),
    roll: float = 0.0,
    dt1: float = 0.0,
    dt2: float = 0.0,
) -> BaseStation:
    """A station at ``position`` (world, m) whose x axis (the middle of its view) points at
    ``target``, its spin axis z as near world up as that allows, then turned by ``roll`` (rad)
    about x; tilt offsets ``dt1, dt2`` (rad)."""
    where = np.asarray(position, dtype=float)
    x = np.asarray(target, dtype=float) - where
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, 1.0]) - x[2] * x
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    y, z = c * y + s * z, -s * y + c * z
    return BaseStation.from_rotation(np.column_stack([x, y, z]), tuple(where), dt1, dt2)


def _errors(fitted: BaseStation, truth: BaseStation) -> tuple[float, float]:
    """Position error (m) and rotation error (rad, angle of the relative rotation)."""
    position = float(np.linalg.norm(np.array(fitted.position) - truth.position))
    relative = fitted.rotation.T @ truth.rotation
    angle = math.acos(max(-1.0, min(1.0, (np.trace(relative) - 1) / 2)))
    return position, angle


@pytest.fixture(scope="module")
def sweep_model() -> SweepModel:
    return SweepModel()


DOWN = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # station x -> world -z
#: Stations away from the defaults, each with tilt offsets of its own: high in a corner
#: (rolled), straight above the track (the Euler angles' gimbal lock), and low behind the track
#: standing upright (spin axis 10 degrees off vertical: the tilt offsets' weakest view).
AWAY = (
    look_at((2.2, -1.6, 1.4), roll=0.3, dt1=0.035, dt2=-0.02),
    BaseStation.from_rotation(DOWN, (0.3, -0.2, 2.2), -0.045, 0.05),
    look_at((-3.0, 0.5, 0.5), dt1=0.01, dt2=0.06),
)
