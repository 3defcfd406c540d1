"""Tests of crs_core.estimation.noise: the noise the estimators assume."""

import math

import pytest

from crs_core.errors import FieldError
from crs_core.estimation import (
    EstimatorNoise,
)
from crs_core.estimation.noise import noise_in_file, noise_mapping, with_noise
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


def test_a_parameter_files_noise_section_overrides_the_defaults(tmp_path):
    """``noise:`` entries replace those fields (lists become tuples); a file without the
    section, or no file, gives the defaults."""
    path = tmp_path / "params.yaml"
    path.write_text("parameters: {m: 0.2}\nnoise:\n  process_std: [0.004, 0.004, 0.004, 1, 1, 6]\n")
    noise = noise_in_file(path)
    assert noise.process_std == (0.004, 0.004, 0.004, 1, 1, 6)
    assert noise.lighthouse_std == EstimatorNoise().lighthouse_std
    plain = tmp_path / "plain.yaml"
    plain.write_text("parameters: {m: 0.2}\n")
    assert noise_in_file(plain) == EstimatorNoise() == noise_in_file(None)
    written = noise_mapping(noise, ["process_std", "wheel_std"])
    assert written == {"process_std": [0.004, 0.004, 0.004, 1.0, 1.0, 6.0], "wheel_std": 2.5}
    document = {"parameters": {"m": 0.2}, "noise": {"wheel_std": 9.0, "process_std": [1] * 6}}
    assert with_noise(document, noise, ["process_std"]) == {
        "parameters": {"m": 0.2},
        "noise": {"wheel_std": 9.0, "process_std": [0.004, 0.004, 0.004, 1.0, 1.0, 6.0]},
    }


@pytest.mark.parametrize(
    ("section", "field"),
    [
        ("  process_stdev: [1, 1, 1, 1, 1, 1]", r"noise\.process_stdev: unknown"),
        ("  process_std: [0.01, 0.01]", r"noise\.process_std: needs 6 values"),
        ("  lighthouse_std: -1", r"noise\.lighthouse_std"),
    ],
)
def test_a_bad_noise_entry_is_refused_naming_the_file_and_the_entry(tmp_path, section, field):
    path = tmp_path / "params.yaml"
    path.write_text(f"parameters: {{}}\nnoise:\n{section}\n")
    with pytest.raises(FieldError, match=rf"params\.yaml: {field}"):
        noise_in_file(path)
