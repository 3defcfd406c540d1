"""Tests of crs_core.identification.prediction_error: the prediction-error fit."""

from __future__ import annotations

import pytest

from crs_core.identification.prediction_error import fit_prediction_error
from crs_core.identification.validation import (
    predict_open_loop,
    validation_errors,
)
from crs_core.model import CarModel


def test_prediction_error_fit_recovers_a_wrong_motor_constant(drive):
    """A 25 % wrong Cm1 (the rest true): the fit lands near the truth and the metric drops to
    the level of the true parameters."""
    truth = CarModel().parameters
    wrong = CarModel(parameters=truth.updated({"Cm1": 0.75 * truth.value("Cm1")}))
    evaluations = []
    result = fit_prediction_error(
        drive, wrong, ["Cm1"], horizon_s=1.0, every=5, progress=lambda i, r: evaluations.append(r)
    )
    assert result.parameters.value("Cm1") == pytest.approx(truth.value("Cm1"), rel=0.05)
    assert result.rmse_m < 0.5 * result.rmse_initial_m
    assert result.evaluations == len(evaluations) > 2
    true_error = validation_errors(drive, predict_open_loop(drive, CarModel(), 1.0))
    assert result.rmse_m < 2.0 * true_error["position_rmse_m"]


def test_prediction_error_fit_refuses_unknown_names(drive):
    with pytest.raises(ValueError, match="nope"):
        fit_prediction_error(drive, CarModel(), ["nope"])
