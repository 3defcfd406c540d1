"""What every node process shares: start-up, parameter helpers, clean shutdown, QoS."""

from __future__ import annotations

import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Sensor and command streams: reliable with a queue deep enough for 250 Hz bursts.
STREAM_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
)
#: Estimates and the estimator's query log: reliable and transient-local, the last
#: ``LOG_DEPTH`` messages kept for a subscriber that joins late (a recorder discovering the topic
#: after the first estimates were published gets them; volatile subscribers, like the
#: controller, still match and get only new messages).
LOG_DEPTH = 1000
LOG_QOS = QoSProfile(
    depth=LOG_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
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


def throttled_warning(node: Node, period: float = 1.0) -> Callable[[str], None]:
    """A function logging ``node``'s warnings at most once per ``period`` s (per function).

    rclpy's own ``throttle_duration_sec`` is throttled per call site (so one line of code shared
    by several topics lets only the first topic's warning through) and inspects the caller's
    frame and source on every call, ~1 ms even when it suppresses the message: on a 250 Hz
    stream of bad or late data that is enough to make a node fall behind.
    """
    last = [-math.inf]

    def warn(message: str) -> None:
        now = time.monotonic()
        if now - last[0] >= period:
            last[0] = now
            node.get_logger().warning(message)

    return warn


class CheckedSubscription:
    """A raw subscription whose messages are validated before ``handle`` sees them.

    The CDR bytes are deserialized here (a message that does not deserialize, e.g. of another
    type or truncated, is dropped instead of raising inside the executor), then ``parse``
    converts and validates it (``ValueError`` drops it). Each drop logs a warning naming the
    problem, throttled to one a second per topic; :attr:`dropped` counts them.

    :meth:`take_pending` handles every message already waiting in the queue. rclpy's executor
    runs a due timer before the messages queued behind it and takes one message per
    subscription per wake-up, so a node that fell behind would otherwise compute at its timer
    without data that are already in the process.
    """

    def __init__(
        self,
        node: Node,
        msg_type: type,
        topic: str,
        parse: Callable[[Any], Any],
        handle: Callable[[Any], None],
        what: str,
    ) -> None:
        self.dropped = 0
        self._msg_type, self._topic, self._what = msg_type, topic, what
        self._parse, self._handle = parse, handle
        self._warn = throttled_warning(node)
        self.subscription = node.create_subscription(
            msg_type, topic, self._on_message, STREAM_QOS, raw=True
        )

    def _on_message(self, data: bytes) -> None:
        from rclpy.serialization import deserialize_message

        try:
            value = self._parse(deserialize_message(bytes(data), self._msg_type))
        except Exception as error:
            self.dropped += 1
            self._warn(f"dropped malformed {self._what} on {self._topic}: {error}")
            return
        self._handle(value)

    def take_pending(self) -> int:
        """Handle every message waiting in the queue, in arrival order; how many there were."""
        taken = 0
        with self.subscription.handle:
            while True:
                message = self.subscription.handle.take_message(self._msg_type, True)
                if message is None:
                    return taken
                self._on_message(message[0])
                taken += 1


def subscribe_checked(
    node: Node,
    msg_type: type,
    topic: str,
    parse: Callable[[Any], Any],
    handle: Callable[[Any], None],
    what: str,
) -> CheckedSubscription:
    """Subscribe raw to ``topic``, every message validated (see :class:`CheckedSubscription`)."""
    return CheckedSubscription(node, msg_type, topic, parse, handle, what)


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
    except Exception:
        if rclpy.ok():
            raise  # a real failure while running
        # the context was shut down (Ctrl-C, SIGTERM) under a running callback, e.g. mid-publish
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
