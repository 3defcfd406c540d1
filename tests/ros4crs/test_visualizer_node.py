"""The visualizer node built in this process (rclpy): how it reads a car's messages between two
scene ticks. Serving a running stack is driven by tests/integration/test_visualizer.py."""

from __future__ import annotations

import time

import numpy as np
import pytest

from crs_core.estimation import PoseFix
from ros4crs import conversions

#: Ports of their own (no other test serves there).
PORT, PAGE_PORT = 18791, 18792


def test_every_fix_between_two_ticks_is_read_and_only_the_newest_state(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two stations' fixes arriving within one scene tick are both drawn (events); of two
    estimates only the newest is read (a state: one deserialisation a tick)."""
    import rclpy
    from rclpy.serialization import serialize_message

    from ros4crs.visualizer_node import VisualizerNode

    monkeypatch.setenv("ROS_DOMAIN_ID", "175")  # its own (the suite's tests use others)
    parameters = [f"port:={PORT}", f"page_port:={PAGE_PORT}", "cars:=car1"]
    rclpy.init(args=["--ros-args", *[a for p in parameters for a in ("-p", p)]])
    try:
        node = VisualizerNode()
        try:
            watch = node.watches["car1"]
            # as the graph's discovery subscribes them
            for topic, msgtype in (
                ("/car1/lighthouse_fix", "geometry_msgs/msg/PoseWithCovarianceStamped"),
                ("/car1/estimate/state", "chronos_msgs/msg/CarState"),
            ):
                node.topics[topic] = node._subscribe(topic, msgtype, watch)
            fixes, states = node.topics["/car1/lighthouse_fix"], node.topics["/car1/estimate/state"]
            assert fixes is not None and states is not None
            for k in range(2):  # one fix of each station, within one tick
                fix = PoseFix(5.0 + 0.01 * k, np.array([1.0, 0.5 * k, 0.1]), np.eye(3), 0.0, (k,))
                node._on_message("/car1/lighthouse_fix", fixes, serialize_message(
                    conversions.pose_fix_msg(fix)
                ))  # fmt: skip
            for stamp in (6.0, 6.1):
                state = conversions.car_state_msg(np.array([0.5, 0.2, 0.0, 1.0, 0.0, 0.0]), stamp)
                node._on_message("/car1/estimate/state", states, serialize_message(state))
            node._read_pending()
            view = watch.view(time.monotonic())
            np.testing.assert_allclose(view.fixes[:, :2], [[1.0, 0.0], [1.0, 0.5]])
            assert view.stamp == pytest.approx(6.1)
            node._read_pending()  # nothing new: nothing read again
            assert len(watch.view(time.monotonic()).fixes) == 2
            _online_parameters_are_read_and_a_malformed_message_is_dropped(node, watch)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


def _online_parameters_are_read_and_a_malformed_message_is_dropped(node, watch) -> None:
    from rclpy.serialization import serialize_message

    from chronos_msgs.msg import OnlineParameters

    topic = "/car1/estimate/parameters"
    node.topics[topic] = entry = node._subscribe(topic, "chronos_msgs/msg/OnlineParameters", watch)
    assert entry is not None
    good = OnlineParameters(names=["Cm1"], values=[0.28], stds=[0.01], informed=[True])
    node._on_message(topic, entry, serialize_message(good))
    node._read_pending()
    ((name, value),) = watch.view(time.monotonic()).parameters.items()
    assert name == "Cm1" and (value.value, value.std, value.informed) == (0.28, 0.01, True)
    bad = OnlineParameters(names=["Cm1", "grip"], values=[0.2], stds=[0.01], informed=[True])
    node._on_message(topic, entry, serialize_message(bad))
    node._read_pending()  # dropped with a warning: the last good values stay
    assert watch.view(time.monotonic()).parameters["Cm1"].value == 0.28
