"""The RK4 substep is chosen from the model's measured fastest dynamics."""

import numpy as np

from crs_core.model import MAX_SUBSTEP, CarModel
from crs_core.model.stability import largest_stable_step, operating_grid


def test_max_substep_is_stable_at_every_speed_with_margin():
    """MAX_SUBSTEP is at most 1/1.5 of the largest stable RK4 step over 0..3 m/s."""
    h = largest_stable_step(CarModel(), operating_grid(np.linspace(0.0, 3.0, 31)))
    assert MAX_SUBSTEP * 1.5 <= h


def test_one_step_at_30_hz_is_unstable_at_low_speed():
    """One RK4 step of 1/30 s is unstable at 0.5 m/s but stable at 1.5 m/s (why substeps)."""
    model = CarModel()
    assert largest_stable_step(model, operating_grid([0.5])) < 1 / 30
    assert largest_stable_step(model, operating_grid([1.5])) > 1 / 30
