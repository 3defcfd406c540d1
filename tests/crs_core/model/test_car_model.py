"""Tests of crs_core.model.car_model: substepped integration, pickling, a model from a file."""

import numpy as np
import pytest
import yaml

from crs_core.model import CarModel
from crs_core.model.car_model import effects_in_file


def test_model_pickles_by_its_constructor_arguments():
    """A model with effects and changed values crosses a process boundary unchanged."""
    import pickle

    model = CarModel({"gyro_bias": {"gyro_bias": 0.07}, "steering_lag": None}, n_base_stations=2)
    model = CarModel(
        {"gyro_bias": None, "steering_lag": None},
        n_base_stations=2,
        parameters=model.parameters.updated({"Cm1": 0.9}),
    )
    copy = pickle.loads(pickle.dumps(model))
    assert copy.tag == model.tag and copy.nx == model.nx
    np.testing.assert_array_equal(copy.parameters.vector(), model.parameters.vector())
    x = model.initial_state([0.1, 0.2, 0.3, 1.0, 0.05, 0.4], [0.1, 0.3])
    f_copy = copy.dynamics_function(x, [0.1, 0.3], copy.parameters.vector())
    f_model = model.dynamics_function(x, [0.1, 0.3], model.parameters.vector())
    np.testing.assert_array_equal(np.asarray(f_copy), np.asarray(f_model))


def test_substepping_integrates_long_intervals_stably():
    """A 1/30 s step at 0.3 m/s with substeps matches 1 ms steps; a single RK4 step blows up."""
    model = CarModel()
    p = model.parameters.vector()
    x0, u = np.array([0, 0, 0, 0.3, 0.05, 0.5]), np.array([0.2, 0.1])
    fine = x0
    for _ in range(200):
        fine = model.numeric.step(fine, u, p, 0.001)
    coarse = x0
    for _ in range(6):
        coarse = model.numeric.step(coarse, u, p, 1 / 30)
    np.testing.assert_allclose(coarse, fine, atol=1e-5)
    single = model.step_function(1)
    x = x0
    for _ in range(6):
        x = np.array(single(x, u, p, 1 / 30)).ravel()
    assert not np.allclose(x, fine, atol=1e-2)


def test_a_model_from_a_parameter_file_and_effects(tmp_path):
    """The file's values apply; an effect's own value wins over the file; no file: defaults."""
    path = tmp_path / "car.yaml"
    path.write_text("parameters:\n  m: 0.25\n  tau_steer: 0.2\n")
    model = CarModel.from_file(path, {"steering_lag": 0.04}, n_base_stations=2)
    assert model.parameters.value("m") == 0.25
    assert model.parameters.value("tau_steer") == 0.04
    assert model.n_base_stations == 2 and [e.name for e in model.effects] == ["steering_lag"]
    assert CarModel.from_file(None).parameters.value("m") == CarModel().parameters.value("m")
    path.write_text("parameters:\n  warp: 1.0\n")
    with pytest.raises(KeyError, match=r"car\.yaml: unknown parameter\(s\) \['warp'\]"):
        CarModel.from_file(path)


def test_effects_of_a_parameter_file_are_those_whose_parameters_it_names(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"parameters": {"m": 0.25, "tau_steer": 0.07, "gyro_bias": 0}}))
    assert sorted(effects_in_file(path)) == ["gyro_bias", "steering_lag"]
    path.write_text(yaml.safe_dump({"parameters": {"m": 0.25}}))
    assert effects_in_file(path) == []
    path.write_text("parameters: [unclosed")
    assert effects_in_file(path) == []  # the parameter loader names what is wrong
    assert effects_in_file(tmp_path / "missing.yaml") == []
    assert effects_in_file(tmp_path / "missing.yaml") == []


def test_a_model_from_a_file_has_the_effects_it_names(tmp_path):
    """A discrepancy's params.yaml (with an effect's parameter) rebuilds its model."""
    path = tmp_path / "params.yaml"
    path.write_text("parameters:\n  m: 0.25\n  gyro_bias: 0.1\n")
    model = CarModel.from_file(path)
    assert [e.name for e in model.effects] == ["gyro_bias"]
    assert model.parameters.value("gyro_bias") == 0.1
    both = CarModel.from_file(path, ["steering_lag"])
    assert sorted(e.name for e in both.effects) == ["gyro_bias", "steering_lag"]  # registry order
