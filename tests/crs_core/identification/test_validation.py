"""Tests of crs_core.identification.validation: the reusable open-loop predictor."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.identification.reference import LIGHTHOUSE_REFERENCE
from crs_core.identification.validation import (
    OpenLoopPredictor,
    horizon_index,
    predict_open_loop,
    process_residuals,
    validate,
)
from crs_core.model import CarModel


def test_predictor_reuses_its_build_for_other_parameters(drive):
    """predict(p) with another parameter vector equals a fresh prediction with those values."""
    model = CarModel()
    predictor = OpenLoopPredictor(drive, model, horizon_s=1.0)
    slower = model.parameters.updated({"Cm1": 0.8 * model.parameters.value("Cm1")})
    fresh = OpenLoopPredictor(
        drive, CarModel(parameters=slower), horizon_s=1.0, states=predictor.states
    ).predict()
    reused = predictor.predict(slower.vector())
    np.testing.assert_allclose(reused.positions, fresh.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reused.outputs, fresh.outputs, rtol=0, atol=1e-12)
    same = predict_open_loop(drive, model, horizon_s=1.0)
    np.testing.assert_array_equal(predictor.predict().positions, same.positions)


def test_validation_without_reference_states_scores_against_the_lighthouse(drive):
    """Without x the position RMSE is taken against the samples' Lighthouse fixes and named so:
    on a simulated drive 12 mm against 8 mm with the truth (the fixes' own error, 8 mm median,
    adds to the prediction's); the per-channel figures do not change."""
    model = CarModel()
    truth, _ = validate(drive, model, model.parameters, horizon_s=1.0)
    bare, _ = validate(replace(drive, x=None), model, model.parameters, horizon_s=1.0)
    assert bare["reference"] == LIGHTHOUSE_REFERENCE and truth["reference"] == "simulation truth"
    with_truth, with_fixes = (
        truth["position_rmse_m"]["identified"],
        bare["position_rmse_m"]["identified"],
    )
    assert abs(with_fixes - with_truth) < 0.01
    assert bare["channel_rms"] == truth["channel_rms"]


def test_a_trajectorys_own_process_residuals_retrace_it(drive):
    """Predicted open loop with the process residuals of the true trajectory added, every start
    follows the truth (to rounding); without them the model's prediction departs from it (the
    truth's substeps are the simulator's, not the predictor's)."""
    model = CarModel()
    truth = drive.x
    residuals = process_residuals(drive, model, truth)
    predictor = OpenLoopPredictor(drive, model, horizon_s=1.0, states=truth, every=10)
    retraced = predictor.predict(outputs=False, disturbances=residuals)
    index = horizon_index(drive, retraced)
    inside = np.isfinite(retraced.positions[..., 0])
    np.testing.assert_allclose(retraced.positions[inside], truth[index][inside][:, :2], atol=1e-9)
    assert np.abs(residuals).max() < 1e-3  # the model is the truth's: only integration error
    with pytest.raises(FieldError, match="disturbances"):
        predictor.predict(disturbances=residuals[1:])
