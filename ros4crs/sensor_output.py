"""How the simulator and the bridge publish a car's sensor readings.

By default the readings go out in batches on ``sensors/batch`` (``chronos_msgs/SensorBatch``):
everything produced during one ``batch_period`` in one message. A car gives about 700 readings a
second (IMU and wheel encoders at 250 Hz, Lighthouse sweeps), and a message costs its publisher
and every subscriber a serialisation and a wake-up whatever its size (measured on this suite's
Fast DDS: ~0.15 ms to publish and ~0.4 ms of a subscriber's CPU per message, a 7-reading batch
as much as one ``Imu``); batches of 10 ms cut the messages of a car seven-fold, for at most 10 ms
more delay, well inside the estimator's ``lag``. With ``sensor_messages`` ``each`` every reading
is its own message on its own topic (``sensors/imu``, ``sensors/wheel_speeds``, ...), for ROS tools
that want ``sensor_msgs/Imu``. The estimator node takes both forms.

Parameters (declared by :func:`declare_sensor_output`; default, description and bounds: the
fields of :class:`SensorOutputSettings`): ``sensor_messages`` and ``batch_period``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from rclpy.node import Node

from crs_core.errors import FieldError
from crs_core.measurements import Measurement
from crs_core.settings import Settings, non_negative
from ros4crs import conversions
from ros4crs.node_support import STREAM_OUT_QOS
from ros4crs.settings_parameters import SettingsParameters, declare_settings

#: Values of the ``sensor_messages`` parameter.
SENSOR_MESSAGES = ("batch", "each")


@dataclass(frozen=True)
class SensorOutputSettings(Settings):
    """How a node publishes a car's sensor readings.

    Attributes
    ----------
    sensor_messages : {"batch", "each"}
        ``batch``: readings in batches on ``sensors/batch``; ``each``: one message per reading
        (``sensors/imu``, ...).
    batch_period : float
        Longest a reading waits for its batch, s (0: a batch per step).
    """

    sensor_messages: str = "batch"
    batch_period: float = non_negative(0.01)

    def _check_relations(self) -> None:
        if self.sensor_messages not in SENSOR_MESSAGES:
            raise FieldError(
                "sensor_messages",
                f"must be one of {', '.join(SENSOR_MESSAGES)}, got {self.sensor_messages!r}",
            )


#: Both settings, parameters of the simulator and the bridge.
SENSOR_OUTPUT_PARAMETERS = SettingsParameters(
    SensorOutputSettings, ("sensor_messages", "batch_period")
)


class SensorOutput:
    """Publishes measurements in batches (``sensors/batch``) or one message each.

    Parameters
    ----------
    node : Node
        The publishing node (topics relative to its namespace).
    frame_id : str
        The car's body frame.
    messages : str
        ``batch`` or ``each``.
    batch_period : float
        Longest a reading waits for its batch, s, on the clock the caller passes to :meth:`add`.
    """

    def __init__(self, node: Node, frame_id: str, messages: str, batch_period: float) -> None:
        SensorOutputSettings(messages, batch_period)  # checked
        self.frame_id, self.batch_period = frame_id, batch_period
        self._pending: list[Measurement] = []
        self._due = -math.inf
        if messages == "batch":
            from chronos_msgs.msg import SensorBatch

            self.publishers = {
                "batch": node.create_publisher(
                    SensorBatch, conversions.TOPICS["batch"], STREAM_OUT_QOS
                )
            }
        else:
            self.publishers = {
                family: node.create_publisher(msg_type, conversions.TOPICS[family], STREAM_OUT_QOS)
                for family, msg_type in conversions.sensor_message_types().items()
            }
        self.batched = messages == "batch"

    def subscription_count(self) -> int:
        """The fewest subscribers any of the sensor topics has."""
        return min(p.get_subscription_count() for p in self.publishers.values())

    def add(self, measurements: Iterable[Measurement], now: float) -> None:
        """Publish ``measurements``: at once (``each``), or into the batch, which goes out
        when ``now`` (s) has passed the batch period since the previous one."""
        if not self.batched:
            for measurement in measurements:
                family = conversions.topic_family(measurement.sensor)
                self.publishers[family].publish(
                    conversions.measurement_to_msg(measurement, self.frame_id)
                )
            return
        self._pending.extend(measurements)
        if now >= self._due:
            self.flush()
            due = self._due + self.batch_period  # on the grid, or anew after a gap
            self._due = due if due > now else now + self.batch_period

    def flush(self) -> None:
        """Publish the pending batch, if any."""
        if self._pending:
            batch: Any = conversions.batch_msg(self._pending, self.frame_id)
            self._pending = []
            self.publishers["batch"].publish(batch)


def declare_sensor_output(node: Node, frame_id: str) -> SensorOutput:
    """Declare ``sensor_messages`` and ``batch_period`` on ``node``; its :class:`SensorOutput`."""
    settings = declare_settings(node, SENSOR_OUTPUT_PARAMETERS)
    return SensorOutput(node, frame_id, settings.sensor_messages, settings.batch_period)
