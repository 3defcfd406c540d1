"""The simulator node's sensor output parameters (``sensor_messages``, ``batch_period``; the
bridge declares the same) come from :class:`ros4crs.sensor_output.SensorOutputSettings`
(default, description, bounds), with their names, types and defaults of before. No ROS graph:
the parameters' specification alone (a node refusing them at start-up:
``test_node_startup.py``)."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import pytest

from crs_core.errors import FieldError
from ros4crs.node_support import ParameterError
from ros4crs.sensor_output import SENSOR_OUTPUT_PARAMETERS, SensorOutput, SensorOutputSettings


def test_the_sensor_output_parameters_keep_their_names_and_defaults() -> None:
    """As the nodes declared them by hand before (docs/ros-interface.md)."""
    assert SENSOR_OUTPUT_PARAMETERS.parameters == ("sensor_messages", "batch_period")
    values = {f: SENSOR_OUTPUT_PARAMETERS.default(f) for f in SENSOR_OUTPUT_PARAMETERS.fields}
    assert values == {"sensor_messages": "batch", "batch_period": 0.01}
    assert SENSOR_OUTPUT_PARAMETERS.build(values) == SensorOutputSettings()
    assert SENSOR_OUTPUT_PARAMETERS.description("batch_period").startswith(
        "Longest a reading waits for its batch, s"
    )


@pytest.mark.parametrize(
    ("parameter", "value", "message"),
    [
        ("batch_period", -0.01, "must be a finite number >= 0, got -0.01"),
        ("batch_period", float("inf"), "must be a finite number >= 0, got inf"),
        ("sensor_messages", "all", "must be one of batch, each, got 'all'"),
    ],
)
def test_a_bad_sensor_output_parameter_is_refused_naming_it(
    parameter: str, value: Any, message: str
) -> None:
    given = {**asdict(SensorOutputSettings()), parameter: value}
    with pytest.raises(ParameterError) as error:
        SENSOR_OUTPUT_PARAMETERS.build(given)
    assert (error.value.field, error.value.reason) == (parameter, message)
    with pytest.raises(FieldError) as refused:  # the publisher checks them with the same class
        SensorOutput(object(), "car1/base_link", given["sensor_messages"], given["batch_period"])
    assert str(refused.value) == str(error.value)
