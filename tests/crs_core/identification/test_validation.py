"""Tests of crs_core.identification.validation: the reusable open-loop predictor."""

from __future__ import annotations

import numpy as np

from crs_core.identification.validation import (
    OpenLoopPredictor,
    predict_open_loop,
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
