"""Tests of crs_core.calibration.static: known stations recovered from simulated points, with
and without the stations' tilt offsets (no station geometry at all in the points file)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.points import points_from_dict
from crs_core.calibration.static import calibrate_static
from crs_core.errors import FieldError
from crs_core.model.lighthouse import BaseStation
from sim.static_points import grid_layout, simulate_static_points
from tests.crs_core.calibration.conftest import AWAY, STATIONS, _errors


@pytest.mark.parametrize(
    ("yaw_known", "fit_tilt", "position_tol", "angle_tol"),
    [(True, False, 1.5e-3, 1.5e-3), (False, False, 1.5e-3, 1.5e-3), (True, True, 3e-3, 3e-3)],
    ids=["tilts given", "tilts given, yaws unknown", "tilts fitted"],
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
    assert result.fit.tilt_fitted == (fit_tilt, fit_tilt)
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


@pytest.mark.parametrize("yaw_known", [True, False], ids=["yaws known", "yaws unknown"])
def test_stations_from_a_points_file_without_station_geometry(sweep_model, yaw_known):
    """No ``stations`` key: three stations from the sweeps, every tilt offset fitted. Each
    station and tilt offset within 4 sigma of the fit, and the overhead station within 2 mm and
    1 mrad, the corner one within 6 mm and 2.5 mrad (one-sigma 2.5 mm, 1 mrad); the upright one
    behind the track is the weakest (one-sigma 6-8 mm: its symmetric tilt trades off against its
    distance), within 20 mm. With the true tilts all three land within 1 mm."""
    simulated = simulate_static_points(
        AWAY, *grid_layout(24, seed=1), sweeps=20, seed=2, yaw_known=yaw_known
    )
    data = simulated.to_dict()
    del data["stations"]
    points = points_from_dict(data)
    assert points.n_stations == 3 and points.tilts == ((None, None),) * 3
    result = calibrate_static(points, sweep_model=sweep_model)
    assert result.fit.tilt_fitted == (True, True, True)
    caps = ((6e-3, 2.5e-3), (2e-3, 1e-3), (20e-3, 6e-3))
    for fitted, truth, std, cap in zip(
        result.stations, AWAY, result.fit.station_std, caps, strict=True
    ):
        position, angle = _errors(fitted, truth)
        assert position < min(cap[0], 4 * np.linalg.norm(std[3:6]))
        assert angle < min(cap[1], 4 * np.linalg.norm(std[0:3]))
        assert abs(fitted.dt1 - truth.dt1) < 4 * std[6] and abs(fitted.dt2 - truth.dt2) < 4 * std[7]
    given = calibrate_static(simulated, sweep_model=sweep_model)
    assert given.fit.tilt_fitted == (False, False, False)
    for fitted, truth in zip(given.stations, AWAY, strict=True):
        assert _errors(fitted, truth)[0] < 1e-3


def test_a_station_the_sweeps_name_but_never_pair_is_named(sweep_model):
    """Without ``stations``, a file whose sweeps are all of station 1 has a station 0 seen at
    no point: one line naming points and the station."""
    simulated = simulate_static_points([STATIONS[0]], *grid_layout(6, seed=1), sweeps=2, seed=2)
    data = simulated.to_dict()
    del data["stations"]
    for point in data["points"]:
        for entry in point["sweeps"]:
            entry["station"] = 1
    with pytest.raises(FieldError) as caught:
        calibrate_static(points_from_dict(data), sweep_model=sweep_model)
    assert str(caught.value) == (
        "points: station 0 has both light planes at 0 point(s); the fit needs at least 3"
    )
