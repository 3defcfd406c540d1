"""Settings written once: ROS parameters derived from a settings dataclass
(:mod:`ros4crs.settings_parameters`), on a stand-in for a node (no ROS graph)."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import pytest

from crs_core.control.command_delay import CommandDelaySettings
from crs_core.control.supervisor import SupervisorSettings
from crs_core.errors import FieldError, require_non_negative, require_positive
from ros4crs.node_support import ParameterError
from ros4crs.settings_parameters import (
    SettingsParameters,
    attribute_docs,
    declare_fields,
    declare_settings,
)


@dataclass(frozen=True)
class Timing:
    """Timing of something.

    A paragraph that is not an attribute.

    Attributes
    ----------
    period : float
        How often, s; ``period`` of
        the :class:`~crs_core.errors.FieldError` kind.
    low, high : float
        The range, m.
    mode : {"fast", "slow"}
        How.
    count : int
        How many.
    offsets : tuple of float
        Offsets, s.
    nothing : int or None
        No default a parameter can take.

    Notes
    -----
    Not an attribute either.
    """

    period: float = 1
    low: float = 0.0
    high: float = 1.0
    mode: str = "fast"
    count: int = 3
    offsets: tuple[float, ...] = (0.0, 0.5)
    nothing: int | None = None

    def __post_init__(self) -> None:
        require_positive(self, "period")
        require_non_negative(self, "count")
        if not self.low <= self.high:
            raise FieldError("high", f"must not be below low ({self.low:g}), got {self.high!r}")


class FakeNode:
    """What :func:`ros4crs.node_support.declare` uses of a node; ``given`` parameter values."""

    def __init__(self, **given: Any) -> None:
        self.given = given
        self.declared: dict[str, tuple[Any, str]] = {}

    def declare_parameter(self, name: str, default: Any, descriptor: Any) -> Any:
        self.declared[name] = (default, descriptor.description)
        return SimpleNamespace(value=self.given.get(name, default))


SPEC = SettingsParameters(
    Timing, ("period", "high", "mode", "count", "offsets"), rename={"period": "timer_period"}
)


def test_attribute_docs_reads_each_entry_as_plain_text() -> None:
    docs = attribute_docs(Timing)
    assert docs["period"] == "How often, s; period of the FieldError kind."
    assert docs["low"] == docs["high"] == "The range, m."
    assert docs["mode"] == "How."
    assert "Notes" not in docs and "Not an attribute either." not in docs.values()


def test_attribute_docs_include_the_bases() -> None:
    from crs_core.estimation.mhe import MheSettings

    docs = attribute_docs(MheSettings)
    assert docs["horizon"].endswith("number of stages.")
    assert docs["time_offsets"].startswith("Per sensor")  # EstimatorSettings'


def test_parameters_default_to_the_fields_with_their_docs() -> None:
    node = FakeNode()
    settings = declare_settings(node, SPEC)
    assert settings == Timing()
    assert SPEC.parameters == ("timer_period", "high", "mode", "count", "offsets")
    assert list(node.declared) == list(SPEC.parameters)
    assert node.declared["timer_period"] == (1.0, "How often, s; period of the FieldError kind.")
    assert type(node.declared["timer_period"][0]) is float  # a float field's default: a float
    assert node.declared["offsets"][0] == (0.0, 0.5)


def test_given_values_and_other_fields_build_the_settings() -> None:
    node = FakeNode(timer_period=2, mode="slow", offsets=[1, 2])
    settings = declare_settings(node, SPEC, low=0.5)
    assert settings == Timing(period=2.0, low=0.5, mode="slow", offsets=(1.0, 2.0))


def test_a_node_default_and_check_override_the_dataclass() -> None:
    node = FakeNode()
    values = declare_fields(node, SPEC, defaults={"count": 5})
    assert values["count"] == 5 and node.declared["count"][0] == 5
    with pytest.raises(ParameterError, match=r"^count: must be in 1..4, got 7$"):
        declare_fields(
            FakeNode(count=7),
            SPEC,
            checks={"count": lambda v: None if 1 <= v <= 4 else "must be in 1..4"},
        )


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"timer_period": 0.0}, "timer_period: must be a finite number > 0, got 0.0"),
        ({"timer_period": "soon"}, "timer_period: expected a number, got 'soon'"),
        ({"count": 1.5}, "count: expected an integer, got 1.5"),
        ({"high": -1.0}, "high: must not be below low (0), got -1.0"),
    ],
)
def test_a_bad_value_names_the_parameter(given: dict[str, Any], message: str) -> None:
    with pytest.raises(ParameterError) as error:
        declare_settings(FakeNode(**given), SPEC)
    assert str(error.value) == message


def test_a_field_that_is_not_a_parameter_keeps_its_name() -> None:
    with pytest.raises(ParameterError, match=r"^high: must not be below low"):
        SettingsParameters(Timing, ("period",)).build({}, low=2.0)


def test_a_field_without_a_default_needs_the_node_s() -> None:
    spec = SettingsParameters(Timing, ("nothing",))
    with pytest.raises(TypeError, match="needs a default"):
        declare_fields(FakeNode(), spec)
    assert declare_fields(FakeNode(nothing=4), spec, defaults={"nothing": 2}) == {"nothing": 4}


def test_a_spec_names_documented_fields_only() -> None:
    with pytest.raises(TypeError, match="no field 'speed'"):
        SettingsParameters(Timing, ("speed",))
    with pytest.raises(TypeError, match="not among the fields"):
        SettingsParameters(Timing, ("period",), rename={"mode": "kind"})

    @dataclass
    class Undocumented:
        """No attributes section."""

        value: float = 1.0

    with pytest.raises(TypeError, match="is not documented"):
        SettingsParameters(Undocumented, ("value",))


def test_the_controller_and_estimator_parameters_keep_their_defaults() -> None:
    """Names and defaults the nodes declared by hand before (docs/ros-interface.md)."""
    from ros4crs.controller_node import COMMAND_DELAY_PARAMETERS, SUPERVISOR_PARAMETERS
    from ros4crs.estimator_node import REALTIME_PARAMETERS

    node = FakeNode()
    supervision = declare_fields(node, SUPERVISOR_PARAMETERS)
    assert supervision == {
        "stale_timeout": 0.2,
        "degraded_speed": 0.5,
        "ramp_rate": 1.5,
        "rise_rate": 3.0,
        "ok_hold": 1.0,
        "hold_safe": "after_outage",
        "caution_memory": 60.0,
    }
    assert SUPERVISOR_PARAMETERS.parameters == (
        "stale_timeout",
        "degraded_speed",
        "speed_ramp",
        "speed_rise",
        "ok_hold",
        "hold_safe",
        "caution_memory",
    )
    assert SUPERVISOR_PARAMETERS.build(supervision) == SupervisorSettings()
    assert declare_settings(node, COMMAND_DELAY_PARAMETERS) == CommandDelaySettings(initial=0.02)
    assert "command_delay" in node.declared
    timing = declare_settings(node, REALTIME_PARAMETERS)
    assert (timing.rate_hz, timing.lag, timing.max_lag) == (60.0, 0.02, 0.0)
    values = declare_fields(FakeNode(speed_rise=0.0), SUPERVISOR_PARAMETERS)  # types only
    with pytest.raises(ParameterError, match=r"^speed_rise: must be a finite number > 0"):
        SUPERVISOR_PARAMETERS.build(values)
    with pytest.raises(ParameterError, match=r"^command_delay: must not exceed max_delay"):
        declare_settings(FakeNode(command_delay=0.5), COMMAND_DELAY_PARAMETERS)


def test_a_declared_bound_is_the_parameter_s_constraints() -> None:
    """``ros2 param describe`` shows the bound declared on the field; none without one."""
    from ros4crs.controller_node import SUPERVISOR_PARAMETERS
    from ros4crs.estimator_node import REALTIME_PARAMETERS

    class DescribedNode(FakeNode):
        def __init__(self) -> None:
            super().__init__()
            self.constraints: dict[str, str] = {}

        def declare_parameter(self, name: str, default: Any, descriptor: Any) -> Any:
            self.constraints[name] = descriptor.additional_constraints
            return super().declare_parameter(name, default, descriptor)

    node = DescribedNode()
    declare_settings(node, REALTIME_PARAMETERS)
    declare_fields(node, SUPERVISOR_PARAMETERS)
    declare_settings(node, SPEC)  # Timing checks in __post_init__: no declared bound
    assert node.constraints == {
        "rate_hz": "a finite number > 0",
        "lag": "a finite number >= 0",
        "max_lag": "a finite number >= 0",
        "stale_timeout": "a finite number > 0",
        "degraded_speed": "a finite number > 0",
        "speed_ramp": "a finite number > 0",
        "speed_rise": "a finite number > 0",
        "ok_hold": "a finite number >= 0",
        "hold_safe": "",
        "caution_memory": "a finite number >= 0",
        "timer_period": "",
        "high": "",
        "mode": "",
        "count": "",
        "offsets": "",
    }
