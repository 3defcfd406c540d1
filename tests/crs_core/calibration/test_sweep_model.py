"""Tests of crs_core.calibration.sweep_model: the fit's angles equal CarModel's, and the
closed-form start from bearings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.calibration.sweep_model import (
    SweepModel,
    bearings,
    homography,
    start_station,
    station_from_bearings,
    symmetric_tilt,
)
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_PHOTODIODES, BaseStation
from sim.static_points import grid_layout, simulate_static_points
from tests.crs_core.calibration.conftest import STATIONS, _errors, look_at


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


def _floor_angles(station: BaseStation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free photodiode floor points (world, m) and their plane 1 and 2 angles."""
    points = simulate_static_points(
        [station], *grid_layout(12, seed=3), sweeps=1, seed=0, sensors=_ideal()
    )
    world, alpha1, alpha2 = [], [], []
    for point in points.points:
        c, s = math.cos(point.yaw), math.sin(point.yaw)
        world.extend(point.position + np.array(RECORDED_PHOTODIODES) @ np.array([[c, s], [-s, c]]))
        alpha1.extend(point.mean_angles(0, 1))
        alpha2.extend(point.mean_angles(0, 2))
    return np.array(world), np.array(alpha1), np.array(alpha2)


@pytest.mark.parametrize("delta", [-0.05, 0.0, 0.04])
def test_a_symmetric_tilt_is_read_off_the_homography(delta: float):
    """Tilts (delta, -delta) unknown: the start gets them, and the station, back exactly."""
    base = STATIONS[0]
    truth = BaseStation(base.angles, base.position, delta, -delta)
    world, alpha1, alpha2 = _floor_angles(truth)
    start = start_station(world, alpha1, alpha2)
    assert start.dt1 == pytest.approx(delta, abs=1e-9)
    assert start.dt2 == pytest.approx(-delta, abs=1e-9)
    position, angle = _errors(start, truth)
    assert position < 1e-9 and angle < 1e-9


def test_a_station_upright_over_the_floor_starts_its_tilts_at_zero():
    """Spin axis 10 degrees off the floor normal: the homography cannot tell the tilt from the
    distance, so the start keeps 0 instead of a noisy guess; known tilts are used as given."""
    truth = look_at((-3.0, 0.5, 0.5), dt1=-0.05, dt2=0.05)
    world, alpha1, alpha2 = _floor_angles(truth)
    assert symmetric_tilt(homography(world, bearings(alpha1, alpha2, 0.0, 0.0))) == 0.0
    start = start_station(world, alpha1, alpha2)
    assert (start.dt1, start.dt2) == (0.0, 0.0)
    known = start_station(world, alpha1, alpha2, (truth.dt1, truth.dt2))
    position, angle = _errors(known, truth)
    assert position < 1e-9 and angle < 1e-9


def _ideal():
    from sim.sensors import SensorSuite

    return SensorSuite().ideal()
