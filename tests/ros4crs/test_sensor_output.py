"""``SensorOutput``: batches go out once per period, every reading once and in order; its
settings (``sensor_messages``, ``batch_period``, parameters of the simulator and the bridge)
come from :class:`~ros4crs.sensor_output.SensorOutputSettings` with their names and defaults
of before."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.measurements import Measurement
from ros4crs import conversions
from ros4crs.node_support import ParameterError
from ros4crs.sensor_output import SENSOR_OUTPUT_PARAMETERS, SensorOutput, SensorOutputSettings


class FakePublisher:
    def __init__(self, topic: str) -> None:
        self.topic, self.sent = topic, []

    def publish(self, msg: Any) -> None:
        self.sent.append(msg)

    def get_subscription_count(self) -> int:
        return 2


class FakeNode:
    """Only what ``SensorOutput`` asks of a node."""

    def __init__(self) -> None:
        self.publishers: dict[str, FakePublisher] = {}

    def create_publisher(self, msg_type: type, topic: str, qos: object) -> FakePublisher:
        self.publishers[topic] = FakePublisher(topic)
        return self.publishers[topic]


def packet(t: float) -> list[Measurement]:
    """What one 250 Hz step of a car gives: an IMU and a wheel-speed reading."""
    return [
        Measurement(t, "imu", [0.1, 0.2, t]),
        Measurement(t, "wheel_encoders", [t, t, t, t]),
    ]


def test_batches_go_out_on_a_period_grid_with_every_reading_once_in_order() -> None:
    node = FakeNode()
    output = SensorOutput(node, "car1/base_link", "batch", 0.01)
    steps = 1000 + np.arange(250) * 0.004  # 1 s of a 250 Hz car
    for t in steps:
        output.add(packet(t), t)
    output.flush()
    batches = node.publishers["sensors/batch"].sent
    assert 100 <= len(batches) <= 101  # one per 10 ms, not one per step
    readings = [m for b in batches for m in conversions.batch_from_msg(b).measurements]
    assert [(m.stamp, m.sensor) for m in readings] == [
        (m.stamp, m.sensor) for t in steps for m in packet(t)
    ]
    for batch in batches:  # a reading waits less than a period plus a step
        stamps = [m.stamp for m in conversions.batch_from_msg(batch).measurements]
        assert max(stamps) - min(stamps) < 0.01 + 0.004 + 1e-9
        assert batch.header.frame_id == "car1/base_link"


def test_a_due_batch_leaves_without_new_readings() -> None:
    node = FakeNode()
    output = SensorOutput(node, "base_link", "batch", 0.01)
    output.add(packet(0.0), 0.0)  # the first goes at once
    output.add(packet(0.004), 0.004)  # waits
    batches = node.publishers["sensors/batch"].sent
    assert len(batches) == 1
    output.add((), 0.0101)  # a poll with no packet, once due
    assert len(batches) == 2
    assert [m.stamp for m in conversions.batch_from_msg(batches[1]).measurements] == [0.004] * 2
    output.add((), 0.015)  # nothing pending: nothing published
    assert len(batches) == 2


def test_period_zero_is_a_batch_per_call() -> None:
    node = FakeNode()
    output = SensorOutput(node, "base_link", "batch", 0.0)
    for t in (0.0, 0.004, 0.008):
        output.add(packet(t), t)
    assert len(node.publishers["sensors/batch"].sent) == 3


def test_each_publishes_one_message_per_reading_on_its_topic() -> None:
    node = FakeNode()
    output = SensorOutput(node, "car1/base_link", "each", 0.01)
    output.add([*packet(5.0), Measurement(5.0, "lighthouse/0/2", [1.0] * 4)], 5.0)
    counts = {topic: len(p.sent) for topic, p in node.publishers.items() if p.sent}
    assert counts == {"sensors/imu": 1, "sensors/wheel_speeds": 1, "sensors/lighthouse": 1}
    assert "sensors/batch" not in node.publishers
    assert output.subscription_count() == 2


@pytest.mark.parametrize(
    ("messages", "period", "field"),
    [("every", 0.01, "sensor_messages"), ("batch", -0.01, "batch_period")],
)
def test_bad_settings_name_the_parameter(messages: str, period: float, field: str) -> None:
    with pytest.raises(ValueError, match=f"^{field}"):
        SensorOutput(FakeNode(), "base_link", messages, period)


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
