"""A polled CheckedSubscription: the executor never runs it; the node takes batches.

The estimator node takes its sensor messages at its update tick this way (no executor wake-up per
message). The batch keeps arrival order and each message's receive time, converts plain messages
through the fast path, and drops, counts and logs malformed ones exactly as the callback path.
"""

from __future__ import annotations

import math
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.serialization import serialize_message

from chronos_msgs.msg import WheelSpeeds
from crs_core.measurements import Measurement
from ros4crs import conversions
from ros4crs.node_support import STREAM_QOS, CheckedSubscription


@pytest.fixture
def ros_context(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", "58")
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.mark.parametrize("fast", [True, False])
def test_polled_subscription_takes_batches_in_order_and_drops_malformed(
    ros_context: Context, fast: bool
) -> None:
    node = rclpy.create_node("polled", namespace="/car7", context=ros_context)
    sender = rclpy.create_node("publisher", context=ros_context)
    executor = EventsExecutor(context=ros_context)  # as the nodes spin (make_executor)
    handled: list[object] = []
    subscription = CheckedSubscription(
        node,
        WheelSpeeds,
        "sensors/wheel_speeds",
        conversions.wheel_speeds_from_msg,
        handled.append,
        "wheel_encoders",
        polled=True,
        fast_parse=conversions.wheel_speeds_from_cdr if fast else None,
    )
    warnings: list[str] = []
    subscription._warn = warnings.append  # the node's throttled logger
    publisher = sender.create_publisher(WheelSpeeds, "/car7/sensors/wheel_speeds", STREAM_QOS)
    try:
        # it is the node's subscription in the graph
        infos = sender.get_subscriptions_info_by_topic("/car7/sensors/wheel_speeds")
        assert [(i.node_namespace, i.node_name) for i in infos] == [("/car7", "polled")]
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        before = time.time_ns()
        stamps = [1.0 + 0.004 * k for k in range(30)]
        cdr = serialize_message(
            conversions.measurement_to_msg(Measurement(0.5, "wheel_encoders", [1.0] * 4))
        )
        for k, stamp in enumerate(stamps):
            if k == 10:
                nan = conversions.measurement_to_msg(Measurement(0.5, "wheel_encoders", [1.0] * 4))
                nan.front_left = math.nan
                publisher.publish(nan)
            if k == 20:
                publisher.publish(cdr[:20])  # truncated: does not deserialize
            speeds = [float(k), 2.0, 3.0, 4.0]
            publisher.publish(
                conversions.measurement_to_msg(Measurement(stamp, "wheel_encoders", speeds))
            )
        executor.add_node(node)
        for _ in range(10):  # the executor does not take them
            executor.spin_once(timeout_sec=0.01)
        values, received = subscription.take_all()
        deadline = time.monotonic() + 10.0
        while len(values) < len(stamps) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)  # still runs nothing of it
            more, times = subscription.take_all()
            values, received = values + more, received + times
        after = time.time_ns()
        assert handled == []
        assert [m.stamp for m in values] == stamps
        assert [m.values[0] for m in values] == list(range(30))
        assert all(before <= r <= after for r in received)
        assert received == sorted(received)
        assert subscription.dropped == 2
        assert warnings[0].startswith(
            "dropped malformed wheel_encoders on sensors/wheel_speeds: wheel speeds: contains NaN"
        )
        assert warnings[1].startswith(
            "dropped malformed wheel_encoders on sensors/wheel_speeds: failed to deserialize"
        )
        assert subscription.take_all() == ([], [])
    finally:
        executor.shutdown()
        subscription.destroy()
        node.destroy_node()
        sender.destroy_node()
