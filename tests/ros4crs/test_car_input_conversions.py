"""``chronos_msgs/CarInput`` <-> core types in both drive modes, and what the boundary refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.measurements import InputSample
from ros4crs import conversions


@pytest.mark.parametrize(
    ("mode", "u", "fields"),
    [
        ("torque", [0.12, -0.4], {"mode": 0, "steer": 0.12, "torque": -0.4, "velocity": 0.0}),
        ("velocity", [-0.2, 1.7], {"mode": 1, "steer": -0.2, "torque": 0.0, "velocity": 1.7}),
        ("velocity", [0.0, -4.5], {"mode": 1, "steer": 0.0, "torque": 0.0, "velocity": -4.5}),
    ],
)
def test_round_trip_writes_the_fields_of_the_mode(mode: str, u: list[float], fields: dict):
    msg = conversions.car_input_msg(np.array(u), 12.25, mode)
    assert {name: getattr(msg, name) for name in fields} == fields
    command = conversions.input_from_msg(msg)
    assert command.stamp == pytest.approx(12.25, abs=1e-9)
    assert command.mode == mode
    np.testing.assert_array_equal(command.u, u)
    stamp, values, read_mode = command  # a plain tuple too
    assert (stamp, values, read_mode) == (command.stamp, command.u, mode)


def test_default_mode_is_torque_and_the_message_constants_agree():
    from chronos_msgs.msg import CarInput

    msg = conversions.car_input_msg(np.array([0.1, 0.3]), 1.0)
    assert msg.mode == CarInput.MODE_TORQUE == conversions.INPUT_MODES["torque"]
    assert CarInput.MODE_VELOCITY == conversions.INPUT_MODES["velocity"]


def test_only_a_torque_command_is_a_model_input():
    torque = conversions.input_from_msg(conversions.car_input_msg(np.array([0.1, 0.3]), 2.0))
    sample = torque.input_sample()
    assert isinstance(sample, InputSample) and sample.stamp == pytest.approx(2.0)
    np.testing.assert_array_equal(sample.u, [0.1, 0.3])
    velocity = conversions.input_from_msg(
        conversions.car_input_msg(np.array([0.1, 1.0]), 2.0, "velocity")
    )
    with pytest.raises(FieldError, match="mode: a 'velocity' command carries no torque"):
        velocity.input_sample()


def test_the_ignored_field_of_each_mode_is_not_validated():
    """Torque mode ignores ``velocity``, velocity mode ``torque`` (as the message says)."""
    msg = conversions.car_input_msg(np.array([0.1, 0.3]), 1.0)
    msg.velocity = math.nan
    assert conversions.input_from_msg(msg).mode == "torque"
    msg = conversions.car_input_msg(np.array([0.1, 2.0]), 1.0, "velocity")
    msg.torque = 7.0
    command = conversions.input_from_msg(msg)
    assert command.mode == "velocity" and command.u[1] == 2.0


def _message(mode: int = 0, steer: float = 0.0, torque: float = 0.0, velocity: float = 0.0):
    from chronos_msgs.msg import CarInput

    msg = CarInput(mode=mode, steer=steer, torque=torque, velocity=velocity)
    conversions.fill_stamp(msg.header.stamp, 3.0)
    return msg


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"mode": 2}, "mode: must be 0 (MODE_TORQUE) or 1 (MODE_VELOCITY), got 2"),
        ({"steer": math.nan}, "steer: contains NaN or inf"),
        ({"mode": 1, "steer": math.inf, "velocity": 1.0}, "steer: contains NaN or inf"),
        ({"torque": math.nan}, "torque: contains NaN or inf"),
        ({"torque": 1.5}, "torque: must be within [-1, 1], got 1.5"),
        ({"mode": 1, "velocity": math.nan}, "velocity: contains NaN or inf"),
        ({"mode": 1, "velocity": -math.inf}, "velocity: contains NaN or inf"),
        ({"mode": 1, "velocity": 5.5}, "velocity: must be within [-5, 5] m/s, got 5.5"),
        ({"mode": 1, "velocity": -12.0}, "velocity: must be within [-5, 5] m/s, got -12.0"),
    ],
)
def test_malformed_inputs_are_refused_naming_the_field(fields: dict, message: str):
    with pytest.raises(FieldError) as error:
        conversions.input_from_msg(_message(**fields))
    assert str(error.value).startswith(message), error.value
    assert error.value.field == message.split(":")[0]


def test_an_unknown_mode_is_refused_when_writing():
    with pytest.raises(
        FieldError, match="mode: must be one of torque, velocity, got 'speed'"
    ) as error:
        conversions.car_input_msg(np.zeros(2), 1.0, "speed")
    assert error.value.field == "mode"


def test_rosbags_messages_convert_the_same(tmp_path):
    """Bag replay reads the rosbags dataclass of the message with the same function."""
    from rclpy.serialization import serialize_message

    from ros4crs.interfaces import typestore

    msg = conversions.car_input_msg(np.array([0.05, 2.5]), 4.5, "velocity")
    store = typestore()
    decoded = store.deserialize_cdr(serialize_message(msg), "chronos_msgs/msg/CarInput")
    command = conversions.input_from_msg(decoded)
    assert command.mode == "velocity"
    np.testing.assert_array_equal(command.u, [0.05, 2.5])
