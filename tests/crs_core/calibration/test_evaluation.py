"""Tests of crs_core.calibration.evaluation: residual reports per point, the farthest-first
order and the calibration error against the number of points."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from crs_core.calibration.evaluation import n_sweep, point_reports, spread_order
from crs_core.calibration.points import load_points
from crs_core.calibration.report import write_geometry
from crs_core.calibration.static import calibrate_static
from crs_core.dataset import Geometry
from crs_core.model.lighthouse import RECORDED_PHOTODIODES
from sim.static_points import grid_layout, simulate_static_points
from tests.crs_core.calibration.conftest import STATIONS, _errors


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
