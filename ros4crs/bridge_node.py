"""Bridge node: one real (or emulated) Chronos car over Wi-Fi UDP <-> the suite's topics.

A thin node around :class:`chronos_bridge.link.CarLink` (one node per car; run several in
their own namespaces, on their own ports, for several cars). A timer polls the link's
non-blocking socket at ``poll_hz`` and publishes each valid ``CarState``:

=========================  ==========================  ===========================================
topic                      type                        content
=========================  ==========================  ===========================================
``sensors/batch``          ``chronos_msgs/SensorBatch`` the readings of the last ``batch_period``
                                                       (10 ms; :mod:`ros4crs.sensor_output`):
                                                       ``imu`` ``[a_x, a_y, ω]`` body frame (board
                                                       x, y negated; ``gyro`` with ``imu_sensor:
                                                       gyro``), ``wheel_encoders`` rad/s when the
                                                       packet has them, ``lighthouse/<bs>/<plane>``
                                                       paired planes, angle offsets, out of view
                                                       dropped (spec; ``CarStateConverter``); with
                                                       ``sensor_messages: each`` one message per
                                                       reading on ``sensors/imu`` (or ``gyro``),
                                                       ``sensors/wheel_speeds``,
                                                       ``sensors/lighthouse`` instead
``sensors/battery``        ``sensor_msgs/BatteryState`` voltage (V), current (A; 0 when the car
                                                       does not send it), when sent
``telemetry/steering``     ``sensor_msgs/JointState``  joint ``steering``: position = measured
                                                       steering angle (rad), effort = steering
                                                       motor power [-1, 1]
``telemetry/drive``        ``sensor_msgs/JointState``  joint ``drive_motor``: effort = drive motor
                                                       power [-1, 1]
``telemetry/velocity``     ``geometry_msgs/TwistStamped`` the car's own v_x estimate (m/s,
                                                       ``twist.linear.x``, body frame), when sent
``input/applied``          ``chronos_msgs/CarInput``   the input the car applies: its measured
                                                       steering angle and drive motor power,
                                                       stamped by its packets (for estimators)
``bridge/diagnostics``     ``std_msgs/String``         JSON every ``diagnostics_period`` s: the
                                                       car's endpoint, receive buckets (with
                                                       ``duplicate``), rejected fields, arrival
                                                       (reordered datagrams, Lighthouse sweeps
                                                       out of order or duplicated), sent counts,
                                                       age of the last packet
=========================  ==========================  ===========================================

Every ``input`` (``chronos_msgs/CarInput``, validated by ``conversions.input_from_msg``) is sent
to the car at once as a ``CarReference`` (``MODE_TORQUE``: throttle + steering angle;
``MODE_VELOCITY``: longitudinal velocity + steering angle), stamped with the host clock: the car
gets commands at the controller's rate (the car stops after 200 ms without one). The newest one
is sent again every ``command_repeat_period`` s (20 ms) for ``command_repeat_for`` s (0.1 s)
after it was first sent (``CarLink.repeat``, at each poll): Wi-Fi loses datagrams in bursts,
and six lost in a row at 30 Hz cut the motors. Nothing is sent before the car is paired.

The battery and ``telemetry/*`` topics are published at ``telemetry_hz`` at most (default 50 Hz:
the packet read when a period of the host's clock has passed); the sensor readings of every
packet go out in batches (a batch is published at the first poll a ``batch_period`` after the
previous one). With telemetry at the car's 250 Hz and 500 socket polls a second (most of them empty)
the bridge took 27-32 % of a core, 21-24 % with 50 Hz telemetry and 200 polls a second (the
node beside an emulated car, three runs each, alternating): several cars share a laptop. A poll
and its batch delay a sample by at most 15 ms, inside the estimator's 20 ms ``lag``.

Stamps: the packet's ``timestamp`` (µs since the Unix epoch) when the car sent one (its clock is
SNTP-synchronised to the host), else the host's wall clock when the poll read the datagram
(up to one poll period, 5 ms at 200 Hz, after its arrival).

Robustness: every value is validated by the codec before anything is published (nothing
NaN/inf or out of range leaves the node; ``BatteryState`` fields the car does not measure are 0,
not the NaN that ``sensor_msgs`` suggests). A datagram from another endpoint than the paired car,
oversize, undecodable or with a bad field is dropped and counted (``CarLink.counts``), with a
warning naming the field (throttled, 1/s); the counts are logged every ``log_period`` s and at
shutdown. Nothing a sender can put in a datagram stops the node.

Parameters: the link's, ``port`` (but not 0), ``bind``, ``car_ip``, ``car_port``, ``imu_sensor``,
``command_repeat_period`` and ``command_repeat_for`` (default, description with the unit and
bounds: the fields of :class:`~chronos_bridge.link.CarLinkSettings`, the last two its
``repeat_period`` and ``repeat_for``); ``poll_hz`` (200), ``telemetry_hz`` (50),
``diagnostics_period`` (1 s), ``log_period`` (10 s); ``sensor_messages`` and ``batch_period``
(:mod:`ros4crs.sensor_output`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node

from chronos_bridge.car_state import Converted
from chronos_bridge.link import CarLink, CarLinkSettings
from ros4crs import conversions
from ros4crs.node_support import (
    STREAM_OUT_QOS,
    STREAM_QOS,
    declare,
    in_range,
    input_subscription,
    positive,
    run,
    throttled_warning,
)
from ros4crs.sensor_output import declare_sensor_output
from ros4crs.settings_parameters import SettingsParameters, declare_settings

#: The bridge's own topics (relative to the car's namespace), besides the sensor topics.
BRIDGE_TOPICS = {
    "battery": "sensors/battery",
    "steering": "telemetry/steering",
    "drive": "telemetry/drive",
    "velocity": "telemetry/velocity",
    "diagnostics": "bridge/diagnostics",
}


#: The link's settings, all parameters (default, description and bounds: the dataclass's).
LINK_PARAMETERS = SettingsParameters(
    CarLinkSettings,
    ("port", "bind", "car_ip", "car_port", "imu_sensor", "repeat_period", "repeat_for"),
    rename={"repeat_period": "command_repeat_period", "repeat_for": "command_repeat_for"},
)


#: ``input/applied`` is published when the car's steering angle moved by more than this, rad ...
APPLIED_STEER_STEP = 0.01
#: ... or its drive power changed, or this long after the last, s.
APPLIED_PERIOD_S = 0.02


class BridgeNode(Node):
    """One car's UDP link as ROS topics (see the module docstring)."""

    def __init__(self, **node_options: Any) -> None:
        super().__init__("bridge", **node_options)
        # a node on port 0 would listen where no car knows to send
        link = declare_settings(self, LINK_PARAMETERS, checks={"port": in_range(1, 65535)})
        poll_hz = declare(self, "poll_hz", 200.0, "socket polls per s", positive)
        telemetry_hz = declare(
            self, "telemetry_hz", 50.0, "battery and telemetry/* at most, Hz", positive
        )
        self._telemetry_period = 1.0 / telemetry_hz
        self._telemetry_due = -float("inf")  # host time from which telemetry is published
        diagnostics_period = declare(
            self, "diagnostics_period", 1.0, "bridge/diagnostics period, s", positive
        )
        log_period = declare(self, "log_period", 10.0, "counts summary log period, s", positive)
        self._warn = throttled_warning(self)
        self.link = CarLink(**dataclasses.asdict(link), warn=self.get_logger().warning)
        self.frame = conversions.body_frame(self.get_namespace())
        self.publish_errors = 0
        self._paired = self.link.endpoint
        from geometry_msgs.msg import TwistStamped
        from sensor_msgs.msg import BatteryState, JointState
        from std_msgs.msg import String

        from chronos_msgs.msg import CarInput

        self._sensors = declare_sensor_output(self, self.frame)
        self._battery = self.create_publisher(BatteryState, BRIDGE_TOPICS["battery"], STREAM_QOS)
        self._steering = self.create_publisher(JointState, BRIDGE_TOPICS["steering"], STREAM_QOS)
        self._drive = self.create_publisher(JointState, BRIDGE_TOPICS["drive"], STREAM_QOS)
        self._velocity = self.create_publisher(TwistStamped, BRIDGE_TOPICS["velocity"], STREAM_QOS)
        self._diagnostics = self.create_publisher(String, BRIDGE_TOPICS["diagnostics"], 10)
        self._applied = self.create_publisher(
            CarInput, conversions.TOPICS["applied_input"], STREAM_OUT_QOS
        )
        self._last_applied: tuple[float, float, float] | None = None  # stamp, steer, torque
        self._inputs = input_subscription(self, self._on_input)
        self.create_timer(1.0 / poll_hz, self._poll)
        self.create_timer(diagnostics_period, self._publish_diagnostics)
        self.create_timer(log_period, lambda: self.get_logger().info(self.link.summary()))
        host, local_port = self.link.address
        peer = (
            f"{link.car_ip}:{link.car_port or 'any port'}"
            if link.car_ip
            else "the first valid sender"
        )
        self.get_logger().info(
            f"listening on UDP {host}:{local_port}, car: {peer}; publishing {link.imu_sensor}, "
            f"stamps from the packet when present, else on receipt"
        )

    # ------------------------------------------------------------------ car -> ROS
    def _poll(self) -> None:
        self.link.repeat()
        now = time.time()
        for converted in self.link.poll(now):
            self._guarded(self._publish, converted)
        self._guarded(self._sensors.add, (), time.monotonic())  # a batch due, no new packet
        if self.link.endpoint != self._paired:
            self._paired = self.link.endpoint
            self.get_logger().info("paired with the car at {}:{}".format(*self._paired))

    def _guarded(self, publish: Callable[..., None], *args: Any) -> None:
        try:
            publish(*args)
        except Exception as error:  # never expected: the values were validated
            self.publish_errors += 1
            self._warn(f"not published: {error!r} ({self.publish_errors} so far)")

    def _publish(self, converted: Converted) -> None:
        from geometry_msgs.msg import TwistStamped
        from sensor_msgs.msg import BatteryState, JointState

        self._sensors.add(converted.measurements, time.monotonic())
        t = converted.telemetry
        self._publish_applied(t.stamp, t.steer_angle, t.drive_power)
        # by the host's clock (a packet's stamp is the car's: a bad one must not mute these)
        now = time.monotonic()
        if now < self._telemetry_due:
            return
        due = self._telemetry_due + self._telemetry_period  # on the grid, or anew after a gap
        self._telemetry_due = due if due > now else now + self._telemetry_period
        if t.battery_voltage is not None:
            battery = BatteryState(voltage=t.battery_voltage, present=True)
            battery.current = 0.0 if t.battery_current is None else t.battery_current
            self._stamp(battery, t.stamp)
            self._battery.publish(battery)
        steering = JointState(name=["steering"], position=[t.steer_angle], effort=[t.steer_power])
        self._stamp(steering, t.stamp)
        self._steering.publish(steering)
        drive = JointState(name=["drive_motor"], effort=[t.drive_power])
        self._stamp(drive, t.stamp)
        self._drive.publish(drive)
        if t.longitudinal_velocity is not None:
            velocity = TwistStamped()
            velocity.twist.linear.x = t.longitudinal_velocity
            self._stamp(velocity, t.stamp)
            self._velocity.publish(velocity)

    def _publish_applied(self, stamp: float, steer: float, torque: float) -> None:
        """``input/applied``: the input the car applies, ``[steer, torque]`` = its measured
        steering angle and its drive motor power (0 during a cut-off), stamped by the car's
        packet; published when the power changes, the angle moves by more than
        :data:`APPLIED_STEER_STEP`, or the last is older than :data:`APPLIED_PERIOD_S`."""
        last = self._last_applied
        if (
            last is not None
            and torque == last[2]
            and abs(steer - last[1]) <= APPLIED_STEER_STEP
            and 0.0 <= stamp - last[0] < APPLIED_PERIOD_S
        ):
            return
        self._last_applied = (stamp, steer, torque)
        self._applied.publish(conversions.car_input_msg((steer, torque), stamp))

    def _stamp(self, msg, seconds: float) -> None:
        msg.header.frame_id = self.frame
        conversions.fill_stamp(msg.header.stamp, seconds)

    # ------------------------------------------------------------------ ROS -> car
    def _on_input(self, command: conversions.CarCommand) -> None:
        self.link.send_command(command.u, command.mode)

    # ------------------------------------------------------------------ reporting
    def diagnostics(self) -> dict:
        """What ``bridge/diagnostics`` carries (JSON)."""
        last = self.link.last_valid
        return {
            "car": None if self.link.endpoint is None else "{}:{}".format(*self.link.endpoint),
            "received": self.link.received,
            "counts": self.link.counts,
            "rejected_fields": self.link.rejected_fields,
            "arrival": self.link.arrival,
            "sent": self.link.sent,
            "inputs_dropped": self._inputs.dropped,
            "publish_errors": self.publish_errors,
            "last_valid_age_s": None if last is None else round(time.time() - last, 3),
        }

    def _publish_diagnostics(self) -> None:
        from std_msgs.msg import String

        self._diagnostics.publish(String(data=json.dumps(self.diagnostics())))

    def destroy_node(self) -> None:
        self.get_logger().info(f"stopping: {self.link.summary()}")
        self.link.close()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    return run(BridgeNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
