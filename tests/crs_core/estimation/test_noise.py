"""Tests of crs_core.estimation.noise: the noise the estimators assume."""

import math

from crs_core.estimation import (
    EstimatorNoise,
)
from crs_core.model import CarModel


def test_effect_states_get_noise_by_name():
    """``steering_lag`` adds ``steer_applied``: its process noise is set by name."""
    noise = EstimatorNoise(extra_process_std={"steer_applied": 0.3})
    model = CarModel(["steering_lag"])
    assert noise.process_std_for(model)[-1] == 0.3
    assert math.isclose(EstimatorNoise().process_std_for(model)[-1], 1e-3)
