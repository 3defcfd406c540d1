"""The MHE's Gauss-Newton step in one compiled call: the same step, covariance and
marginalisation blocks as the numpy and LAPACK reference on the same windows (at start-up, with
the window full, from a poor guess), and the same refusals of what cannot be solved."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.estimation import MheSettings, make_estimator
from crs_core.estimation.mhe import STEP_FRACTIONS, MovingHorizonEstimator
from crs_core.estimation.mhe_native import NativeGaussNewton
from crs_core.estimation.mhe_problem import BandedGaussNewton, StepOutcome
from tests.crs_core.estimation.conftest import _run


@pytest.fixture(scope="module")
def mhe() -> MovingHorizonEstimator:
    estimator = make_estimator(
        "mhe", "lh+imu+we", settings=MheSettings(rate_hz=60.0), inputs="commanded"
    )
    assert isinstance(estimator, MovingHorizonEstimator)
    return estimator


def _window(mhe: MovingHorizonEstimator) -> tuple:
    first, information = mhe._arrival_terms()
    inputs = (mhe._X, mhe._U, mhe._DT, *mhe._weights(), mhe._p, mhe._bounds)
    return inputs, first, information, mhe._arrival.copy()


def _both(mhe: MovingHorizonEstimator, inputs, first, information, mean):
    native = mhe._step_solver
    assert isinstance(native, NativeGaussNewton)
    reference = BandedGaussNewton(mhe._solve_blocks, mhe._cost, STEP_FRACTIONS)
    inputs = tuple(np.array(a, dtype=float) for a in inputs)
    return (
        (native.step(inputs, first, information, mean), native),
        (reference.step(inputs, first, information, mean), reference),
    )


@pytest.mark.parametrize("seconds", [0.3, 4.0])  # start-up (nodes unused) and a full window
def test_the_compiled_step_is_the_reference_step(mhe, drive, seconds: float) -> None:
    queries = np.arange(1, int(seconds * 60) + 1) / 60.0
    _run(mhe, drive, queries)
    inputs, first, information, mean = _window(mhe)
    assert (first > 0) == (seconds < 1.0)
    (code, native), (expected, reference) = _both(mhe, inputs, first, information, mean)
    assert code == expected == StepOutcome.TAKEN
    scale = np.max(np.abs(reference.X))
    np.testing.assert_allclose(native.X, reference.X, rtol=0, atol=1e-9 * scale)
    covariance = reference.covariance
    np.testing.assert_allclose(
        native.covariance, covariance, rtol=1e-7, atol=1e-10 * np.max(np.abs(covariance))
    )
    for ours, theirs in zip(
        native.marginalization_blocks(), reference.marginalization_blocks(), strict=True
    ):
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


def test_from_a_poor_guess_both_backtrack_alike(mhe, drive) -> None:
    _run(mhe, drive, np.arange(1, 121) / 60.0)
    inputs, first, information, mean = _window(mhe)
    X = np.array(inputs[0])
    X[3, :] += 1.5  # every node 1.5 m/s too fast
    X[0, 10] += 0.3
    (code, native), (expected, reference) = _both(mhe, (X, *inputs[1:]), first, information, mean)
    assert code == expected
    if code == StepOutcome.TAKEN:
        np.testing.assert_allclose(native.X, reference.X, rtol=0, atol=1e-8)


def test_a_window_that_cannot_be_solved_is_refused_alike(mhe, drive) -> None:
    _run(mhe, drive, np.arange(1, 61) / 60.0)
    inputs, first, information, mean = _window(mhe)
    X = np.array(inputs[0])
    X[:, 7] = np.nan
    (code, native), (expected, _) = _both(mhe, (X, *inputs[1:]), first, information, mean)
    assert code == expected == StepOutcome.NON_FINITE_COST
    assert native.residuals.shape[1] == X.shape[1]
    singular = np.full_like(information, -1e12)  # an indefinite prior: no Cholesky factor
    (code, _), (expected, _) = _both(mhe, inputs, first, singular, mean)
    assert code == expected == StepOutcome.NOT_POSITIVE_DEFINITE


def test_in_casadis_vm_the_mhe_steps_in_numpy_to_the_same_estimates(mhe, drive, monkeypatch):
    """Without a compiler (CasADi's VM) the MHE takes the reference step: the same estimates
    over half a second of the drive."""
    monkeypatch.setenv("CRS_CODEGEN", "vm")
    in_vm = make_estimator(
        "mhe", "lh+imu+we", settings=MheSettings(rate_hz=60.0), inputs="commanded"
    )
    assert isinstance(in_vm, MovingHorizonEstimator)
    assert isinstance(in_vm._step_solver, BandedGaussNewton)
    queries = np.arange(1, 31) / 60.0
    compiled, _ = _run(mhe, drive, queries)
    interpreted, _ = _run(in_vm, drive, queries)
    np.testing.assert_allclose(interpreted, compiled, rtol=0, atol=1e-8)


@pytest.mark.parametrize(
    "online", [("Cm1",), ("Cm1", "gyro_bias"), ("Cm1", "gyro_bias", "grip")], ids=len
)
def test_the_compiled_step_is_the_reference_step_at_every_state_count(drive, online) -> None:
    """7, 8 and 9 states (the car's 6 and online parameters; GCC 12 once dropped the
    triangular solve of the step at exactly 7): a full window steps as the reference does,
    and no update of the drive falls back."""
    settings = MheSettings(rate_hz=60.0, horizon=12, online_parameters=online)
    mhe = make_estimator("mhe", "lh+imu+we", settings=settings, inputs="commanded")
    assert isinstance(mhe, MovingHorizonEstimator)
    assert mhe.model.nx == 6 + len(online)
    _run(mhe, drive, np.arange(1, 61) / 60.0)
    assert mhe.diagnostics.fallbacks == 0
    inputs, first, information, mean = _window(mhe)
    (code, native), (expected, reference) = _both(mhe, inputs, first, information, mean)
    assert code == expected == StepOutcome.TAKEN
    np.testing.assert_allclose(
        native.X, reference.X, rtol=0, atol=1e-9 * np.max(np.abs(reference.X))
    )
    np.testing.assert_allclose(native.covariance, reference.covariance, rtol=1e-7, atol=1e-12)
