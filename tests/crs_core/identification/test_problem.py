"""Tests of crs_core.identification.problem: the residual layout, substeps and the settings."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.identification import FieData, FieProblem, FieSettings
from crs_core.identification.data import Y_LAYOUT
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.problem import check_fit, substeps_for
from crs_core.model import CarModel
from crs_core.model.car_model import MAX_SUBSTEP


def test_residual_layout_and_substeps(drives):
    """The residual has one row per prior, defect and measurement; substeps <= MAX_SUBSTEP."""
    dataset = drives[0]
    model = identification_model(dataset, [], ROUGH)
    data = FieData.from_dataset(dataset, FieSettings().noise)
    problem = FieProblem(model, data, FieSettings(fit=("Cm1",)), np.zeros(model.nx))
    n = len(dataset.t)
    assert problem.blocks == {
        "theta_prior": 1,
        "x0_prior": model.nx,
        "process": model.nx * (n - 1),
        "measurement": 13 * n,
    }
    assert sum(cols.stop - cols.start for _, cols in Y_LAYOUT) == 13
    for dt in (0.004, 0.0201, 0.1, 0.37):
        assert dt / substeps_for(dt) <= MAX_SUBSTEP + 1e-12
    z = problem.pack(np.array([0.9]), np.ones((n, model.nx)))
    theta, states = problem.unpack(z)
    assert theta == pytest.approx([0.9]) and states.shape == (n, model.nx)


def test_input_delay_cannot_be_fitted():
    model = CarModel(["input_delay"])
    with pytest.raises(FieldError, match="fit: 'input_delay'") as error:
        check_fit(model, ("input_delay",))
    assert error.value.field == "fit"


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"fit": ()}, "fit"),
        ({"fit": ("m", "m")}, "fit"),
        ({"hessian": "bfgs"}, "hessian"),
        ({"process_scale": 0.0}, "process_scale"),
        ({"max_iter": 0}, "max_iter"),
        ({"starts": 0}, "starts"),
    ],
)
def test_bad_fie_settings_name_the_field(settings: dict, field: str):
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        FieSettings(**{"fit": ("m",), **settings})
    assert error.value.field == field
