"""Static Lighthouse calibration: known stations recovered from simulated points."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import yaml

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.evaluation import n_sweep, point_reports, spread_order
from crs_core.calibration.points import load_points, points_from_dict
from crs_core.calibration.report import write_geometry
from crs_core.calibration.static import calibrate_static
from crs_core.calibration.sweep_model import SweepModel, bearings, station_from_bearings
from crs_core.dataset import Geometry
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.chronos import default_base_stations
from crs_core.model.lighthouse import RECORDED_PHOTODIODES, BaseStation
from sim.static_points import grid_layout, simulate_static_points

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


@pytest.mark.parametrize(
    ("yaw_known", "fit_tilt", "position_tol", "angle_tol"),
    [(True, False, 1.5e-3, 1.5e-3), (False, False, 1.5e-3, 1.5e-3), (True, True, 3e-3, 3e-3)],
)
def test_two_stations_recovered_from_noisy_points(
    sweep_model, yaw_known, fit_tilt, position_tol, angle_tol
):
    """24 points, 20 sweeps of 1 mrad noise each: both stations within ~1 mm / 1 mrad."""
    points = simulate_static_points(
        STATIONS,
        *grid_layout(24, seed=1),
        sweeps=20,
        seed=2,
        yaw_known=yaw_known,
        write_tilts=not fit_tilt,
    )
    result = calibrate_static(points, fit_tilt=fit_tilt, sweep_model=sweep_model)
    for fitted, truth in zip(result.stations, STATIONS, strict=True):
        position, angle = _errors(fitted, truth)
        assert position < position_tol
        assert angle < angle_tol
        if fit_tilt:
            assert abs(fitted.dt1 - truth.dt1) < 2e-3 and abs(fitted.dt2 - truth.dt2) < 2e-3
    if not yaw_known:
        truth_yaws = grid_layout(24, seed=1)[1]
        yaw_error = np.abs(wrap_angle(result.yaws - truth_yaws))
        assert yaw_error.max() < 0.03


def test_station_looking_straight_down_is_recovered(sweep_model):
    """Gimbal lock of the model's Euler angles (phi2 = pi/2) does not hurt the fit."""
    down = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # station x -> -z
    truth = BaseStation.from_rotation(down, (0.1, -0.2, 2.0), -0.05, 0.046)
    points = simulate_static_points([truth], *grid_layout(8, seed=4), sweeps=10, seed=5)
    result = calibrate_static(points, sweep_model=sweep_model)
    fitted, std = result.stations[0], result.fit.station_std[0]
    error = np.abs(np.array(fitted.position) - truth.position)
    assert np.all(error < 4 * std[3:6] + 1e-4)  # within the fit's own 4 sigma
    assert _errors(fitted, truth)[1] < 3e-3


def test_residual_reports_and_geometry_yaml(tmp_path, sweep_model):
    """Angle residuals through CarModel equal the fit's; fixes land near the points; the YAML
    is a dataset.yaml geometry block and the points file round-trips."""
    points = simulate_static_points(STATIONS[:1], *grid_layout(10, seed=6), sweeps=20, seed=7)
    points.save(tmp_path / "points.yaml")
    loaded = load_points(tmp_path / "points.yaml")
    assert len(loaded.points) == 10 and loaded.tilts == points.tilts
    result = calibrate_static(loaded, sweep_model=sweep_model)
    reports = point_reports(loaded, result.stations, result.yaws)
    fitted = {
        (
            int(result.point_of[k]),
            int(result.observations.station[k]),
            int(result.observations.plane[k]),
        ): result.fit.residuals[k]
        for k in range(len(result.observations))
    }
    for report in reports:
        for (s, plane), residual in report.angle_residuals.items():
            np.testing.assert_allclose(residual, fitted[(report.index, s, plane)], atol=1e-9)
        assert report.position_error < 3e-3
        assert 0.5e-3 < report.sweep_std[(0, 1)] < 1.5e-3  # the simulated 1 mrad per sweep
    path = write_geometry(tmp_path / "geometry.yaml", result.stations, loaded.photodiodes)
    geometry = Geometry.from_dict(yaml.safe_load(path.read_text())["geometry"])
    np.testing.assert_allclose(
        geometry.base_stations[0].rotation, result.stations[0].rotation, atol=1e-12
    )
    assert geometry.photodiodes == tuple(RECORDED_PHOTODIODES)


def test_spread_order_adds_the_farthest_point_first():
    positions, _ = grid_layout(12)
    order = spread_order(positions)
    assert sorted(order) == list(range(12))
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    assert distance[order[0], order[1]] == pytest.approx(distance.max())


def test_more_points_give_a_better_calibration(sweep_model):
    """Single sweeps, 2 mm reference error, 3 layouts: from 4 to 24 points (farthest-first) the
    reprojected error over all points and the station's true position error both fall, and 6
    points reach < 5 mm mean."""
    all_mean: dict[int, list[float]] = {}
    station_error: dict[int, list[float]] = {}
    for seed in range(3):
        points = simulate_static_points(
            STATIONS[:1], *grid_layout(24, seed=seed), sweeps=1, seed=seed, position_std=2e-3
        )
        rows, order = n_sweep(points, counts=[4, 6, 24])
        for row in rows:
            all_mean.setdefault(row.n, []).append(row.all_mean)
            fitted = calibrate_static(points.subset(order[: row.n]), sweep_model=sweep_model)
            station_error.setdefault(row.n, []).append(_errors(fitted.stations[0], STATIONS[0])[0])
    mean = {n: float(np.mean(v)) for n, v in all_mean.items()}
    truth = {n: float(np.mean(v)) for n, v in station_error.items()}
    assert mean[24] < mean[4]
    assert truth[24] < truth[6] < truth[4]
    assert mean[6] < 5e-3


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"stations": []}, "stations"),
        ({"stations": [{"dt1": "x"}]}, "stations[0].dt1"),
        ({"points": [{"position": [0.0]}]}, "points[0].position"),
        ({"points": [{"position": [0.0, 0.0], "sweeps": []}]}, "points[0].sweeps"),
        (
            {"points": [{"position": [0, 0], "sweeps": [{"station": 3, "plane1": [[0] * 4]}]}]},
            "points[0].sweeps[0].station",
        ),
    ],
)
def test_a_bad_points_file_names_the_field(change: dict, field: str):
    data = {"stations": [{}], "points": [{"position": [0.0, 0.0]}], **change}
    with pytest.raises(FieldError, match=rf"^{re.escape(field)}: ") as error:
        points_from_dict(data)
    assert error.value.field == field
