"""Named parameters: Chronos defaults, validation at the boundary, YAML round trip."""

import math

import numpy as np
import pytest
import yaml

from crs_core.model import CarModel
from crs_core.model.chronos import ROUGH_PRIOR, dynamics_parameters
from crs_core.parameters import Parameter, ParameterSet


def test_model_parameter_vector_follows_names():
    """The model's p vector is laid out in ParameterSet order, looked up by name."""
    model = CarModel()
    p = model.parameters.vector()
    assert p[model.parameters.index("Cd2")] == model.parameters.value("Cd2")
    assert model.np == len(p)


def test_yaml_round_trip(tmp_path):
    """to_yaml then updated_from_yaml reproduces every field."""
    params = CarModel(["steering_lag"]).parameters.updated({"m": 0.25, "tau_steer": 0.07})
    path = tmp_path / "p.yaml"
    params.to_yaml(path)
    again = CarModel(["steering_lag"]).parameters.updated_from_yaml(path)
    assert again.to_dict() == params.to_dict()


def test_yaml_with_plain_numbers_applies_onto_defaults(tmp_path):
    """A YAML of plain numbers (e.g. the rough prior) overrides only those values."""
    path = tmp_path / "prior.yaml"
    path.write_text(yaml.safe_dump({"parameters": ROUGH_PRIOR}))
    params = dynamics_parameters().updated_from_yaml(path)
    assert params.value("Cd0") == 0.014 and params.value("b_car") == 0.088
    assert params.value("m") == 0.242


@pytest.mark.parametrize(
    "content, field",
    [
        ({"parameters": {"m": "heavy"}}, "m"),
        ({"parameters": {"m": float("nan")}}, "m"),
        ({"parameters": {"m": 7.0}}, "m"),
        ({"parameters": {"mass": 0.3}}, "mass"),
        ({"parameters": {"m": {"value": 0.3, "lower": 0.4}}}, "m"),
        ({"params": {}}, "parameters"),
    ],
)
def test_bad_yaml_is_rejected_naming_the_field(tmp_path, content, field):
    """Malformed, non-finite, out-of-bounds or unknown entries raise errors naming the field."""
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(content))
    with pytest.raises((ValueError, KeyError), match=field):
        dynamics_parameters().updated_from_yaml(path)


def test_duplicate_and_inconsistent_parameters_rejected():
    """Duplicate names and inverted bounds are refused."""
    a = Parameter("k", 1.0, "-", 0.0, 2.0, 0.1, "a gain", "car")
    with pytest.raises(ValueError, match="duplicate"):
        ParameterSet([a, a])
    with pytest.raises(ValueError, match="lower bound"):
        Parameter("k", 1.0, "-", 3.0, 2.0, 0.1, "a gain", "car")


def test_base_station_angles_accept_any_rotation():
    """A station looking straight down with phi3 = 2.498 rad (outside the old chart-centred
    bounds) is accepted; angles are wrapped by whole turns, never refused."""
    from crs_core.model.lighthouse import BaseStation, rotation_from_angles

    params = CarModel().parameters.updated({"bs0_phi3": 2.498, "bs0_phi1": 7.0})
    assert params.value("bs0_phi3") == 2.498
    assert math.isclose(params.value("bs0_phi1"), 7.0 - 2 * math.pi)
    assert params["bs0_phi2"].lower == -2 * math.pi and params["bs0_phi2"].upper == 2 * math.pi
    down = rotation_from_angles(math.pi, 0.0, 2.498)  # station z axis pointing at the floor
    station = BaseStation.from_rotation(down, (0.0, 0.0, 2.0), 0.0, 0.0)
    model = CarModel(base_stations=[station])
    np.testing.assert_allclose(
        rotation_from_angles(*(model.parameters.value(f"bs0_phi{k}") for k in (1, 2, 3))),
        down,
        atol=1e-12,
    )
