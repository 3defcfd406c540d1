"""Tests of crs_core.identification.models: the model an identification starts from."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.identification.models import ROUGH, identification_model
from crs_core.model import CarModel
from crs_core.model.chronos import ROUGH_PRIOR


def test_the_model_carries_the_rough_prior_the_effects_and_a_parameter_file(
    drives: list[Dataset], tmp_path: Path
):
    dataset = drives[0]
    rough = identification_model(dataset, ["steering_lag"], ROUGH)
    assert rough.nx == CarModel(["steering_lag"]).nx
    for name, value in ROUGH_PRIOR.items():
        assert rough.parameters.value(name) == pytest.approx(value)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"parameters": {"Cm1": 0.5}}))
    assert identification_model(dataset, [], path).parameters.value("Cm1") == 0.5
    path.write_text(yaml.safe_dump({"parameters": {"mass": 0.3}}))
    with pytest.raises(FieldError, match=r"^model-file: ") as error:
        identification_model(dataset, [], path, field="model-file")
    assert error.value.field == "model-file"
