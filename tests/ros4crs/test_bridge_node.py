"""The bridge node's link parameters come from :class:`chronos_bridge.link.CarLinkSettings`
(default, description, bounds), with their names, types and defaults of before; so do the link's
own defaults and the car stack's first bridge port. No ROS graph: the parameters' specification
alone (a node refusing them at start-up: ``test_node_startup.py``)."""

from __future__ import annotations

from typing import Any

import pytest

from chronos_bridge import DEFAULT_PORT
from chronos_bridge.link import CarLink, CarLinkSettings
from ros4crs.bridge_node import LINK_PARAMETERS
from ros4crs.node_support import ParameterError


def defaults() -> dict[str, Any]:
    """Each link parameter's default, by field."""
    return {field: LINK_PARAMETERS.default(field) for field in LINK_PARAMETERS.fields}


def test_the_link_parameters_keep_their_names_and_defaults() -> None:
    """As the node declared them by hand before (docs/ros-interface.md)."""
    named = {LINK_PARAMETERS.parameter(f): value for f, value in defaults().items()}
    assert named == {
        "port": 20211,
        "bind": "127.0.0.1",
        "car_ip": "",
        "car_port": 0,
        "imu_sensor": "imu",
        "command_repeat_period": 0.02,
        "command_repeat_for": 0.1,
    }
    assert LINK_PARAMETERS.build(defaults()) == CarLinkSettings()


def test_descriptions_are_the_fields_docs_with_their_units() -> None:
    assert LINK_PARAMETERS.description("repeat_period") == (
        "The newest command is sent again this often, s (0: never)."
    )
    assert LINK_PARAMETERS.description("port").startswith("Local UDP port")


@pytest.mark.parametrize(
    ("parameter", "value", "message"),
    [
        ("command_repeat_period", -0.02, "must be a finite number >= 0, got -0.02"),
        ("command_repeat_for", float("nan"), "must be a finite number >= 0, got nan"),
        ("car_ip", "car.local", "not an IPv4 address, got 'car.local'"),
        ("bind", "", "not an IPv4 address, got ''"),
        ("imu_sensor", "accel", "must be one of imu, gyro, got 'accel'"),
        ("car_port", 70000, "must be in 0..65535, got 70000"),
        ("car_port", 20211, "needs car_ip (the port alone cannot pair), got 20211"),
    ],
)
def test_a_bad_link_parameter_is_refused_naming_it(
    parameter: str, value: Any, message: str
) -> None:
    field = {LINK_PARAMETERS.parameter(f): f for f in LINK_PARAMETERS.fields}[parameter]
    with pytest.raises(ParameterError) as error:
        LINK_PARAMETERS.build({**defaults(), field: value})
    assert (error.value.field, error.value.reason) == (parameter, message)


def test_the_link_and_the_car_stack_take_the_settings_defaults() -> None:
    from chronos_bridge import emulator_process
    from launch_scripts.car_stack import HOST_PORT

    with CarLink(port=0) as link:
        assert link.settings == CarLinkSettings(port=0)
    assert HOST_PORT == CarLinkSettings().port == DEFAULT_PORT == emulator_process.DEFAULT_PORT
