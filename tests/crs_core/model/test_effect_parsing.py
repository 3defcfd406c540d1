"""Effects named on a command line or in a node parameter: ``NAME[.PARAM]=VALUE``."""

from __future__ import annotations

import re

import pytest

from crs_core.model import CarModel
from crs_core.model.effects import effect_spec, parse_effect


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("gyro_bias", ("gyro_bias", None, None)),
        ("steering_lag=0.08", ("steering_lag", "tau_steer", 0.08)),
        ("steering_lag.tau_steer=0.1", ("steering_lag", "tau_steer", 0.1)),
        ("input_delay=0", ("input_delay", "input_delay", 0.0)),
        ("gyro_scale=0.1", ("gyro_scale", "gyro_scale_error", 0.1)),
        ("steering_gain=-0.2", ("steering_gain", "steering_gain_error", -0.2)),
        ("torque_deadzone", ("torque_deadzone", None, None)),
        ("lighthouse_offset=0.02", ("lighthouse_offset", "lh_plane1_offset", 0.02)),
        (
            "lighthouse_offset.lh_plane2_offset=0.01",
            ("lighthouse_offset", "lh_plane2_offset", 0.01),
        ),
    ],
)
def test_parse_effect_forms(text: str, expected: tuple):
    """NAME, NAME=VALUE and NAME.PARAM=VALUE parse to (effect, parameter, value)."""
    assert parse_effect(text) == expected


def test_parse_effect_rejects_non_numbers():
    """A value that is not a finite number is a ValueError naming the effect."""
    with pytest.raises(ValueError, match="effect 'steering_lag': 'slow'"):
        parse_effect("steering_lag=slow")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("bogus", "unknown effect 'bogus'; known: steering_offset"),
        ("steering_lag.tau=0.1", "effect 'steering_lag' has no parameter 'tau'"),
        ("steering_lag=nan", "effect 'steering_lag': 'nan' is not a finite number"),
    ],
)
def test_parse_effect_errors_name_what_is_wrong(text: str, message: str):
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_effect(text)


def test_effect_spec_merges_parameters_per_effect():
    parsed = [parse_effect(t) for t in ("gyro_bias", "steering_lag=0.08", "motor_lag")]
    parsed.append(("steering_lag", "tau_steer", 0.1))
    assert effect_spec(parsed) == {
        "gyro_bias": None,
        "steering_lag": {"tau_steer": 0.1},
        "motor_lag": None,
    }


def test_parsed_lighthouse_offset_builds_a_model_with_both_plane_offsets():
    """Both parameters of a two-parameter effect can be set from the command-line form."""
    spec = effect_spec(
        parse_effect(t)
        for t in ("lighthouse_offset=0.02", "lighthouse_offset.lh_plane2_offset=-0.01")
    )
    assert spec == {"lighthouse_offset": {"lh_plane1_offset": 0.02, "lh_plane2_offset": -0.01}}
    model = CarModel(spec)
    assert model.parameters.value("lh_plane1_offset") == 0.02
    assert model.parameters.value("lh_plane2_offset") == -0.01
