"""What every node process shares: start-up, parameter helpers, clean shutdown, QoS."""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Sensor and command streams: reliable with a queue deep enough for 250 Hz bursts.
STREAM_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
)


def declare(node: Node, name: str, default: Any, description: str = "") -> Any:
    """Declare a parameter with a default and return its value."""
    from rcl_interfaces.msg import ParameterDescriptor

    return node.declare_parameter(name, default, ParameterDescriptor(description=description)).value


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``"pkg/msg/Type"``."""
    import importlib

    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def run(make_node: Callable[[], Node], argv: Sequence[str] | None = None) -> int:
    """Initialise rclpy, spin the node until Ctrl-C / SIGTERM / shutdown, clean up.

    ``ROS_AUTOMATIC_DISCOVERY_RANGE`` defaults to ``LOCALHOST`` so no discovery traffic leaves
    the machine unless asked for.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init(args=list(argv) if argv is not None else sys.argv)
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
