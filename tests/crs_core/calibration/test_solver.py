"""Tests of crs_core.calibration.solver: the exact Jacobian of the calibration least squares and
a noise-free fit that gives the geometry back."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.calibration.solver import LighthouseFit, Observations
from crs_core.calibration.sweep_model import SweepModel
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_PHOTODIODES, BaseStation
from tests.crs_core.calibration.conftest import STATIONS, _errors

#: Car poses (x, y, yaw) on the floor, before the common yaw offset the fits solve for.
POSES = np.column_stack(
    [np.linspace(-1.2, 1.2, 12), np.tile([-0.6, 0.0, 0.5], 4), np.linspace(-2.5, 2.5, 12)]
)
#: Observation k: pose POSE_OF[k], station STATION[k], plane PLANE[k] (both planes of both
#: stations at every pose).
POSE_OF, STATION, PLANE = (a.ravel() for a in np.meshgrid(range(12), (0, 1), (1, 2), indexing="ij"))


def _poses(extra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose of each observation turned by the one unknown ``extra[0]`` (rad), and its
    derivative."""
    poses = POSES[POSE_OF] + np.array([0.0, 0.0, extra[0]])
    derivative = np.zeros((len(POSE_OF), 3, 1))
    derivative[:, 2, 0] = 1.0
    return poses, derivative


def _observations(yaw_offset: float) -> Observations:
    """The observed angles, from CarModel's own sweep-angle outputs."""
    model = CarModel(base_stations=list(STATIONS))
    p = model.parameters.vector()
    angles = []
    for k, s, plane in zip(POSE_OF, STATION, PLANE, strict=True):
        pose = POSES[k] + np.array([0.0, 0.0, yaw_offset])
        out = model.numeric.outputs(np.array([*pose, 0.0, 0.0, 0.0]), np.zeros(2), p)
        angles.append(out[f"lighthouse/{s}/{plane}"])
    return Observations(STATION, PLANE, np.array(angles))


def _moved(station: BaseStation, shift: float, turn: float) -> BaseStation:
    return BaseStation(
        tuple(a + turn for a in station.angles),
        tuple(v + shift for v in station.position),
        station.dt1,
        station.dt2,
    )


def _fit(
    sweep_model: SweepModel, yaw_offset: float, shift: float, turn: float, **options: bool
) -> LighthouseFit:
    """The fit of the observations at ``yaw_offset`` (the pose unknown), starting from the
    stations moved by ``shift`` (m) and turned by ``turn`` (rad)."""
    return LighthouseFit(
        _observations(yaw_offset),
        [_moved(s, shift, turn) for s in STATIONS],
        RECORDED_PHOTODIODES,
        _poses,
        n_extra=1,
        sweep_model=sweep_model,
        **options,
    )


@pytest.mark.parametrize("fit_tilt", [True, [False, True]], ids=["all tilts", "station 1's"])
def test_the_jacobian_matches_central_differences(sweep_model: SweepModel, fit_tilt):
    """With the tilts (of every station, or of one), the photodiodes and the pose unknown free,
    every column of the exact Jacobian equals the central difference of the residuals."""
    fit = _fit(sweep_model, 0.02, 0.03, 0.02, fit_tilt=fit_tilt, fit_photodiodes=True)
    z = fit.start_vector(np.array([0.01])) + np.random.default_rng(0).normal(0, 1e-3, fit.n_vars)
    _, jacobian = fit.evaluate(z)
    assert np.all(np.isfinite(jacobian))
    h = 1e-6
    for k in range(fit.n_vars):
        step = np.zeros(fit.n_vars)
        step[k] = h
        numeric = (fit.evaluate(z + step, False) - fit.evaluate(z - step, False)) / (2 * h)
        np.testing.assert_allclose(jacobian[:, k], numeric, atol=1e-6)


def test_noise_free_sweeps_give_the_stations_and_the_unknown_back(sweep_model: SweepModel):
    """From stations 5 cm and 0.03 rad off and a zero yaw offset, the fit lands on the truth
    with residuals at rounding level."""
    fit = _fit(sweep_model, 0.05, 0.05, 0.03)
    result = fit.solve(np.array([0.0]))
    assert result.extra[0] == pytest.approx(0.05, abs=1e-9)
    assert np.max(np.abs(result.residuals)) < 1e-9
    for fitted, truth in zip(result.stations, STATIONS, strict=True):
        position, angle = _errors(fitted, truth)
        assert position < 1e-8 and angle < 1e-8
    assert result.photodiodes == tuple(RECORDED_PHOTODIODES)


def test_tilts_fitted_per_station(sweep_model: SweepModel):
    """Station 1's tilts start 0.03 rad off and are fitted; station 0's stay as given (no
    sigma), and both stations come back."""
    start = [STATIONS[0], BaseStation(STATIONS[1].angles, STATIONS[1].position, 0.0, 0.0)]
    truth = STATIONS[1]
    assert abs(truth.dt1) > 0.03 and abs(truth.dt2) > 0.03
    fit = LighthouseFit(
        _observations(0.0),
        start,
        RECORDED_PHOTODIODES,
        _poses,
        n_extra=1,
        fit_tilt=[False, True],
        sweep_model=sweep_model,
    )
    result = fit.solve(np.array([0.0]))
    assert result.tilt_fitted == (False, True)
    assert np.all(result.station_std[0, 6:] == 0.0)
    assert (result.stations[0].dt1, result.stations[0].dt2) == (STATIONS[0].dt1, STATIONS[0].dt2)
    assert result.stations[1].dt1 == pytest.approx(truth.dt1, abs=1e-8)
    assert result.stations[1].dt2 == pytest.approx(truth.dt2, abs=1e-8)
    for fitted, want in zip(result.stations, STATIONS, strict=True):
        position, angle = _errors(fitted, want)
        assert position < 1e-8 and angle < 1e-8
