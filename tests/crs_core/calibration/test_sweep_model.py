"""Tests of crs_core.calibration.sweep_model: the fit's angles equal CarModel's, and the
closed-form start from bearings."""

from __future__ import annotations

import math

import numpy as np

from crs_core.calibration.sweep_model import SweepModel, bearings, station_from_bearings
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_PHOTODIODES
from sim.static_points import grid_layout, simulate_static_points
from tests.crs_core.calibration.conftest import STATIONS


def test_sweep_model_matches_the_car_model():
    """The fit's angles equal CarModel's lighthouse outputs (one model, different chart)."""
    model = CarModel(base_stations=list(STATIONS))
    p = model.parameters.vector()
    sweeps = SweepModel()
    rng = np.random.default_rng(0)
    poses = np.column_stack(
        [rng.uniform(-1, 1, 20), rng.uniform(-1, 1, 20), rng.uniform(-3, 3, 20)]
    )
    for s, station in enumerate(STATIONS):
        theta = np.array([0.0, 0.0, 0.0, *station.position, station.dt1, station.dt2])
        ours = sweeps.angles(poses, theta, station.rotation, np.array(RECORDED_PHOTODIODES))
        for q, row in zip(poses, ours, strict=True):
            out = model.numeric.outputs(np.array([*q, 0, 0, 0]), np.zeros(2), p)
            expected = np.concatenate([out[f"lighthouse/{s}/1"], out[f"lighthouse/{s}/2"]])
            np.testing.assert_allclose(row, expected, atol=1e-12)


def test_closed_form_start_is_exact_without_noise():
    """Planar DLT on noise-free bearings returns the station to rounding."""
    station = STATIONS[1]
    points = simulate_static_points(
        [station], *grid_layout(6, seed=3), sweeps=1, seed=0, sensors=_ideal()
    )
    world, directions = [], []
    for point in points.points:
        yaw = point.yaw
        c, s = math.cos(yaw), math.sin(yaw)
        world.extend(point.position + np.array(RECORDED_PHOTODIODES) @ np.array([[c, s], [-s, c]]))
        directions.extend(
            bearings(point.mean_angles(0, 1), point.mean_angles(0, 2), station.dt1, station.dt2)
        )
    rotation, position = station_from_bearings(np.array(world), np.array(directions))
    np.testing.assert_allclose(rotation, station.rotation, atol=1e-9)
    np.testing.assert_allclose(position, station.position, atol=1e-9)


def _ideal():
    from sim.sensors import SensorSuite

    return SensorSuite().ideal()
