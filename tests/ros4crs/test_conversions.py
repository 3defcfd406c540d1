"""The message conversions refuse a malformed message with a :class:`FieldError` naming the
field (``.field``; the message is ``"<field>: <reason>"``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.measurements import Measurement
from ros4crs import conversions


def _imu(**fields: float) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "imu", [0.1, 0.2, 0.3]))
    for name, value in fields.items():
        if name == "omega":
            msg.angular_velocity.z = value
        else:
            setattr(msg.linear_acceleration, name, value)
    return msg


def _sweep(plane: int = 1, angle: float = 2.0) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "lighthouse/0/1", [2.0] * 4))
    msg.plane = plane
    msg.angles = [angle, 2.0, 2.0, 2.0]
    return msg


def _pose(w: float = 1.0, x: float = 0.5) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "pose", [0.5, 0.25, 0.0]))
    msg.pose.orientation.w = w
    msg.pose.position.x = x
    return msg


def _wheels(rear_left: float = 1.0, nanosec: int = 0) -> Any:
    msg = conversions.measurement_to_msg(Measurement(2.0, "wheel_encoders", [1.0] * 4))
    msg.rear_left = rear_left
    msg.header.stamp.nanosec = nanosec
    return msg


def _state(status: int = 0, vx: float = 1.0) -> Any:
    msg = conversions.car_state_msg(np.zeros(6), 4.0)
    msg.status, msg.vx = status, vx
    return msg


def _query() -> Any:
    msg = conversions.query_msg(3.0, False, {"sensors/imu": 2.5})
    msg.streams = ["sensors/imu", "sensors/pose"]
    return msg


@pytest.mark.parametrize(
    ("convert", "msg", "field", "reason"),
    [
        (conversions.imu_from_msg, _imu(omega=math.nan), "angular_velocity.z", "contains NaN"),
        (conversions.imu_from_msg, _imu(y=math.inf), "linear_acceleration", "contains NaN"),
        (conversions.wheel_speeds_from_msg, _wheels(math.nan), "wheel speeds", "contains NaN"),
        (
            conversions.wheel_speeds_from_msg,
            _wheels(nanosec=1_000_000_000),
            "header.stamp.nanosec",
            "must be in [0, 1e9)",
        ),
        (conversions.lighthouse_from_msg, _sweep(plane=3), "plane", "must be 1 or 2, got 3"),
        (conversions.lighthouse_from_msg, _sweep(angle=math.nan), "angles", "contains NaN"),
        (conversions.pose_from_msg, _pose(w=3.0), "pose.orientation", "not a unit quaternion"),
        (conversions.pose_from_msg, _pose(x=math.inf), "pose.position", "contains NaN"),
        (conversions.state_from_msg, _state(vx=math.nan), "state", "contains NaN"),
        (conversions.status_from_msg, _state(status=7), "status", "must be 0 (ok)"),
        (conversions.query_from_msg, _query(), "newest", "1 stamps for 2 streams"),
    ],
)
def test_a_malformed_message_is_refused_naming_the_field(
    convert: Callable[[Any], Any], msg: Any, field: str, reason: str
) -> None:
    with pytest.raises(FieldError) as error:
        convert(msg)
    assert error.value.field == field
    assert error.value.reason.startswith(reason), error.value
    assert str(error.value) == f"{field}: {error.value.reason}"


def test_a_negative_or_non_finite_stamp_is_refused_when_writing() -> None:
    for seconds in (-1.0, math.nan):
        with pytest.raises(FieldError) as error:
            conversions.stamp_ns(seconds)
        assert error.value.field == "header.stamp"
