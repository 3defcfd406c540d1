"""Tests of the predicted FIE covariance of a drive (crs_core.discrepancy.drive_information)."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.discrepancy.drive_information import (
    LIGHTHOUSE_VIEW_LIMIT,
    DriveInformation,
    DriveSamples,
    log_det,
    marginal_covariance,
)
from crs_core.identification.data import FieData
from crs_core.identification.problem import FieProblem, FieSettings, prior_std
from crs_core.identification.uncertainty import parameter_uncertainty
from crs_core.model import CarModel
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset

FIT = ("Iz", "Df", "Bf", "Dr", "Br", "Cm1", "Cd2", "r")


@pytest.fixture(scope="module")
def drive():
    return simulate_dataset(4.0, 3)


def _samples(dataset, measured=None) -> DriveSamples:
    seen = np.isfinite(dataset.y)
    return DriveSamples(
        dataset.t, dataset.x, dataset.u, seen if measured is None else measured, seen[:, 0]
    )


def test_the_view_limit_is_the_simulators() -> None:
    from sim.simulator import LIGHTHOUSE_VIEW_LIMIT as SIMULATOR_LIMIT

    assert LIGHTHOUSE_VIEW_LIMIT == SIMULATOR_LIMIT


def test_the_prediction_is_the_fies_laplace_covariance(drive) -> None:
    """The Kalman recursion and the FIE's reduced Hessian at the true states agree (the FIE
    holds commands over its segments, the recursion from sample to sample: a few percent, 7 %
    on Iz in these 4 s)."""
    model = CarModel()
    settings = FieSettings(fit=FIT, process_scale=SIM_PROCESS_SCALE)
    problem = FieProblem(model, FieData.from_dataset(drive, settings.noise), settings, drive.x[0])
    z = problem.pack(problem.theta_prior, drive.x)
    fie = parameter_uncertainty(
        problem.jacobian_function()(z).sparse(), FIT, problem.theta_prior, problem.theta_std
    )
    period = float(np.mean(np.diff(drive.t)))
    info = DriveInformation(model, FIT, period, process_scale=SIM_PROCESS_SCALE)
    predicted = info.posterior_covariance(_samples(drive), np.diag(problem.theta_std**2))
    np.testing.assert_allclose(np.sqrt(np.diag(predicted)), fie.std, rtol=0.1)


def test_a_parameter_no_measured_channel_sees_keeps_its_prior(drive) -> None:
    """The wheel radius enters only the encoders: without them its sigma is its prior's."""
    model = CarModel()
    measured = np.isfinite(drive.y)
    measured[:, 8:12] = False
    info = DriveInformation(model, FIT, 0.02, process_scale=SIM_PROCESS_SCALE)
    prior = np.diag([prior_std(model, n) ** 2 for n in FIT])
    after = info.posterior_covariance(_samples(drive, measured), prior)
    i = FIT.index("r")
    assert np.sqrt(after[i, i]) == pytest.approx(np.sqrt(prior[i, i]), rel=1e-9)
    assert np.all(np.diag(after) <= np.diag(prior) * (1 + 1e-12))
    j = FIT.index("Cm1")
    assert after[j, j] < 0.5 * prior[j, j]


def test_data_add_information_and_the_marginal_is_the_open_block(drive) -> None:
    model = CarModel()
    info = DriveInformation(model, FIT, 0.02, process_scale=SIM_PROCESS_SCALE)
    prior = np.diag([prior_std(model, n) ** 2 for n in FIT])
    half = len(drive.t) // 2
    short = DriveSamples(
        *(a[:half] for a in (drive.t, drive.x, drive.u)),
        np.isfinite(drive.y[:half]),
        np.ones(half, bool),
    )
    full = info.posterior_covariance(_samples(drive), prior)
    part = info.posterior_covariance(short, prior)
    open_names = ("Dr", "Br")
    assert log_det(marginal_covariance(full, FIT, open_names)) < log_det(
        marginal_covariance(part, FIT, open_names)
    )
    block = marginal_covariance(full, FIT, open_names)
    assert block[0, 0] == full[FIT.index("Dr"), FIT.index("Dr")]
    assert log_det(np.diag([1.0, -1.0])) == float("inf")
