"""Tests of crs_core.identification.report: the identified parameter file and the summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.identification import FieSettings, identify
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.report import result_summary, write_params_yaml
from crs_core.identification.solve import FieResult
from crs_core.model import CarModel


@pytest.fixture(scope="module")
def result(drives: list[Dataset]) -> FieResult:
    """Cm1 and Iz identified from the rough prior on 2 s of a simulated drive."""
    dataset = drives[0]
    k = 100
    short = Dataset(t=dataset.t[:k], u=dataset.u[:k], y=dataset.y[:k], x=dataset.x[:k])
    model = identification_model(short, [], ROUGH)
    return identify(short, model, FieSettings(fit=("Cm1", "Iz"), tol=1e-9))


def test_the_parameter_file_loads_back_with_the_identified_values_and_std(
    result: FieResult, tmp_path: Path
):
    path = write_params_yaml(result, tmp_path / "params.yaml")
    header = path.read_text().splitlines()[:3]
    assert header[1].startswith(f"# Cm1: {result.theta_prior[0]:.6g} -> {result.theta[0]:.6g}")
    loaded = CarModel().parameters.updated_from_yaml(path)
    for i, name in enumerate(result.fit):
        assert loaded.value(name) == pytest.approx(result.theta[i], rel=1e-12)
        assert loaded[name].prior_std == pytest.approx(result.uncertainty.std[i], rel=1e-12)
    assert loaded.value("m") == result.parameters.value("m")


def test_the_summary_holds_each_parameter_and_the_fit_rms_of_each_channel(result: FieResult):
    summary = result_summary(result)
    assert list(summary["parameters"]) == ["Cm1", "Iz"]
    cm1 = summary["parameters"]["Cm1"]
    assert cm1["value"] == result.theta[0] and cm1["std"] == result.uncertainty.std[0]
    assert summary["samples"] == 100 and summary["cost"] == result.cost
    used = result.data.weight[:, 12] > 0
    rms = np.sqrt(np.mean((result.outputs[used, 12] - result.data.y[used, 12]) ** 2))
    assert summary["fit_channel_rms"][Y_CHANNELS[12]] == pytest.approx(rms, rel=1e-12)
