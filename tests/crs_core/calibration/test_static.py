"""Tests of crs_core.calibration.static: known stations recovered from simulated points."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.static import calibrate_static
from crs_core.model.lighthouse import BaseStation
from sim.static_points import grid_layout, simulate_static_points
from tests.crs_core.calibration.conftest import STATIONS, _errors


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
