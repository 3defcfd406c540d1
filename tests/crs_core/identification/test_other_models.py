"""Identification of models other than the dynamic bicycle: the kinematic bicycle identified
on its own simulated recording, fitted only to the sensors it explains, its file naming it."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from crs_core.estimation.noise import EstimatorNoise
from crs_core.identification.data import Y_LAYOUT, FieData
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.problem import FieSettings, default_fit
from crs_core.identification.report import write_params_yaml
from crs_core.identification.solve import identify
from crs_core.model import CarModel
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset


@pytest.fixture(scope="module")
def kinematic_drive():
    """20 s of the path follower on a simulated kinematic car."""
    return simulate_dataset(20.0, 5, model=CarModel(model="kinematic"))


def test_the_fie_weighs_only_what_the_model_explains(kinematic_drive):
    data = FieData.from_dataset(kinematic_drive, EstimatorNoise())
    explained = data.explained_by(CarModel(model="kinematic").plant.explains)
    columns = dict(Y_LAYOUT)
    assert not explained.weight[:, columns["gyro"]].any()  # the kinematic bicycle: no gyro
    np.testing.assert_array_equal(
        explained.weight[:, columns["wheel_encoders"]], data.weight[:, columns["wheel_encoders"]]
    )
    assert explained.weight[:, columns["gyro"]].shape[1] == 1
    assert data.explained_by(CarModel().plant.explains).weight.tolist() == data.weight.tolist()


def test_the_kinematic_bicycle_is_identified_from_the_rough_prior(kinematic_drive, tmp_path):
    """Its axle distances and the encoders' geometry come back close to the truth it was
    simulated with (the forces per mass on a near-constant-speed drive stay near the prior),
    and the file it writes names the model, so --params needs no --model."""
    model = identification_model(kinematic_drive, (), ROUGH, model="kinematic")
    assert model.plant.name == "kinematic"
    fit = default_fit(model)
    assert "m" not in fit and "Df" not in fit
    result = identify(kinematic_drive, model, FieSettings(fit=fit, process_scale=SIM_PROCESS_SCALE))
    truth = CarModel(model="kinematic").parameters
    for name, tolerance in (("lf", 0.1), ("lr", 0.1), ("r", 0.01), ("b_car", 0.05)):
        error = result.parameters.value(name) / truth.value(name) - 1
        assert abs(error) < tolerance, (name, error)
    written = write_params_yaml(result, tmp_path / "params.yaml")
    assert yaml.safe_load(written.read_text())["model"] == "kinematic"
    reloaded = CarModel.from_file(written)
    assert reloaded.plant.name == "kinematic"
    assert reloaded.parameters.value("lf") == pytest.approx(result.parameters.value("lf"))
    assert result.car_states.shape == (len(kinematic_drive.t), 6)
