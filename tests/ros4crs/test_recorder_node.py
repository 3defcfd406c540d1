"""The recorder node built in this process (rclpy): when and how it subscribes to a topic. Its
recording of a running stack is driven by tests/integration (test_replay, test_robustness)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.integration.stack_probe import wait_for


def test_a_topic_seen_before_its_publisher_waits_for_it_and_takes_its_durability(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A topic that appears through a subscription first (the estimator's ``input`` before the
    controller is up) is not subscribed yet: its QoS is unknown, and a volatile subscription
    would miss what a transient-local publisher keeps for late joiners (a bag then lacked the
    estimator's first command and its replay was not exact, CI 2026-11-27). Once the
    publisher is there, the recorder subscribes transient-local, as the publisher offers."""
    import rclpy
    from rclpy.qos import DurabilityPolicy

    from chronos_msgs.msg import CarInput
    from ros4crs.node_support import STREAM_OUT_QOS, STREAM_QOS
    from ros4crs.recorder_node import RecorderNode

    topic = "/car1/input"
    monkeypatch.setenv("ROS_DOMAIN_ID", "174")  # its own (the suite's tests use others)
    rclpy.init(args=["--ros-args", "-p", f"output:={tmp_path / 'bag'}", "-p", f"topics:={topic}"])
    try:
        recorder = RecorderNode()
        other = rclpy.create_node("estimator_and_controller")
        try:
            other.create_subscription(CarInput, topic, lambda _: None, STREAM_QOS)
            wait_for(lambda: topic in dict(recorder.get_topic_names_and_types()), 10.0, "the topic")
            recorder._discover()
            assert topic not in recorder.connections  # a subscription only: not yet
            other.create_publisher(CarInput, topic, STREAM_OUT_QOS)
            wait_for(lambda: recorder.get_publishers_info_by_topic(topic), 10.0, "its publisher")
            recorder._discover()
            assert topic in recorder.connections
            mine = [
                info
                for info in other.get_subscriptions_info_by_topic(topic)
                if info.node_name == recorder.get_name()
            ]
            assert [info.qos_profile.durability for info in mine] == [
                DurabilityPolicy.TRANSIENT_LOCAL
            ]
        finally:
            other.destroy_node()
            recorder.destroy_node()
    finally:
        rclpy.shutdown()
