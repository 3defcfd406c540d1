"""Tests of crs_core.estimation.noise: the noise the estimators assume."""

import math

import pytest

from crs_core.errors import FieldError
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


def test_whole_numbers_are_standard_deviations_too_and_a_bad_one_is_named():
    """``wheel_std=25`` (an int, one value or four) is a standard deviation like 25.0; a zero
    is refused naming the field."""
    assert EstimatorNoise(wheel_std=25).measurement_std("wheel_encoders").tolist() == [25.0] * 4
    assert EstimatorNoise(wheel_std=(1, 2, 3, 4)).measurement_std("wheel_encoders")[3] == 4.0
    with pytest.raises(FieldError, match=r"noise\.wheel_std"):
        EstimatorNoise(wheel_std=0)
